"""``compgw commission``, read as its steps: commission (the order of the steps), steps
(what every step shares: state, configs, drift references), then one module a step or
refinement (thermal, rotary, refine, takeup, after, best, short, command), the configs it
makes the gateway run (configs), the drift references (drift), the report (report,
ident_text), ``--recheck`` (recheck) and the command line (cli).

commissioning imports plans, thermal, fitting, measuring and reporting (and
``..cli_common``); within calibration only the command line (``..commands``) imports it.
"""
