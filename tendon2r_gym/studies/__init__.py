"""Studies and benchmarks behind results/: speed, time step, actuation map, learnability.

Each module has a ``main(argv)`` and a thin wrapper in scripts/.
"""
