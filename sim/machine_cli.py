"""``compgw sim --random-machine SEED | --real-machine NAME [--out DIR]``: write a machine's
files (sim config, truth, gateway config, machine.json) and exit. 0 ok, 1 bad input."""

from __future__ import annotations


def write_machine_dir(seed: int | None, roughness: str, real: str | None, out: str | None) -> int:
    """Dispatch to the random or the real-data generator."""
    if real is not None:
        from sim.real_machines import main as real_main

        return real_main(real, out)
    from sim.random_machine import main as random_main

    assert seed is not None
    return random_main(seed, roughness, out)
