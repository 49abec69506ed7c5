"""Validation layer: analytic fields with exact decompositions and the papers'
examples, shared by tests and benchmarks."""
