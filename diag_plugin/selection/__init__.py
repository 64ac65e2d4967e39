"""Model selection from data: the candidate features, held-out scoring, the screen of dead
times and the spans and set counts of a variable.

Below both of its users: the workbench's ``diag explain`` ranks candidate effects with it,
and ``diag unit build`` chooses each test's inputs with it, so a unit's models are chosen by
the same rules the user sees in ``explain``.
"""
