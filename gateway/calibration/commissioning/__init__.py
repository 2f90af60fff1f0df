"""``compgw commission``, read as its steps.

:mod:`.commission` wires the collaborators once and runs the four steps in order:
:mod:`.identify` (1), :mod:`.fit` (2), :mod:`.rounds` (3, with :mod:`.refine`,
:mod:`.best`), :mod:`.after` (4). Each step is a small class given what it works with
in its constructor; none inherits another.

The shared collaborators, each passed in:

- :mod:`.axes` — the commissioned axes as configured (read-only);
- :mod:`.record` — what is done, on disk (``commission.json``): what a resume reads;
- :mod:`.drift` — the drift references, read between runs;
- :mod:`.stager` — the config writer (each phase's config over the gateway's file);
- :mod:`.budget` — machine time: costs, what is left, what is kept back;
- :mod:`.steps` — the step runner (a plan run once, resumable) and the settings.

Step helpers: :mod:`.planner` (the plans), :mod:`.thermal` (warm-ups), :mod:`.rotary`
(rotary axes and the judging units), :mod:`.takeup`, :mod:`.short` (a short budget),
:mod:`.command` (the printed plan, what the command asks). Around them: :mod:`.configs`
(what each phase's config holds), :mod:`.report` and :mod:`.ident_text` (the report),
:mod:`.recheck` (``--recheck``) and :mod:`.cli` (the command line).

commissioning imports plans, thermal, fitting, measuring and reporting (and
``..cli_common``); within calibration only the command line (``..commands``) imports it.
"""
