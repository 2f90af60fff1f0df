"""What a run shows its reader: ``compgw report`` (ISO 230-2 figures, plots, one HTML
file) and ``compgw export`` (pitch tables between compgw CSV, LinuxCNC and FANUC style).

reporting imports plans and fitting only; never measuring or commissioning.
"""
