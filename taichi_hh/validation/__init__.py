"""Validation layer: what the tests and the benchmarks measure the library
against, and how they measure it.

Exact answers: :mod:`fields` (analytic fields with exact decompositions),
:mod:`colin_examples` (Colin et al. 2006's examples and Table 1),
:mod:`rt` (Rayleigh-Taylor growth against linear theory).  Inputs:
:mod:`layouts` (lattices and samplings).  Measures: :mod:`measures` (errors,
statistics, orders), :mod:`conditioning` (the flow's clean-up system as a
matrix), :mod:`krylov_comparison` (BiCGSTAB against GMRES with the same
preconditioner).  Sweeps: :mod:`sweep` (configurations run in worker
processes, one CSV row each) and :mod:`stability` (the status of a stability
map cell).  The scripts in ``benchmarks/`` drive these and write tables and
charts.
"""
