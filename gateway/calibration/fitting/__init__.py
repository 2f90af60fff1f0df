"""From readings to tables and models (pure): ISO 230-2 statistics, pitch tables and their
smoothing, the planar, cyclic, linkage and take-up fits, commissioning's verdicts and
refined tables (adaptive, sweep), and the checked files a config references (outputs,
plane_frame). A fit that needs a run of its own keeps that run's plan beside it: the take-up
ladder in takeup_fit, the warm-up, the dense scans at the cyclic fit's spacing and the
sweep in plans_scans.

fitting imports plans and thermal only; never measuring, reporting or commissioning.
"""
