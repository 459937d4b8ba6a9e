"""The commands built on the core (benchmarks, strategy comparison, file inspection) and the synthetic
takes they and the tests measure with. Nothing below ``tools`` imports from here."""
