"""Table and model files: compgw CSV, LinuxCNC compensation files, planar point sets.

Readers refuse a malformed line with an error naming the file and line (never a silently
shortened table). Writers replace the target atomically: nothing is ever half written.
"""

from .atomic import atomic_write_text
from .cyclic_file import read_cyclic, write_cyclic
from .linkage_file import read_linkage, write_linkage
from .linuxcnc import read_linuxcnc, write_linuxcnc
from .pitch_csv import read_pitch_csv, write_pitch_csv
from .planar_file import load_planar_model, read_planar_csv, write_planar_csv

__all__ = [
    "atomic_write_text",
    "load_planar_model",
    "read_cyclic",
    "read_linkage",
    "read_linuxcnc",
    "read_pitch_csv",
    "read_planar_csv",
    "write_cyclic",
    "write_linkage",
    "write_linuxcnc",
    "write_pitch_csv",
    "write_planar_csv",
]
