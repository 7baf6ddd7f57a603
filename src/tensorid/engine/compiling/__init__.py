"""The compiled programs (the engine's lowest part; it imports nothing else of the
engine): a sweep's jit-compiled entry point and the one way arrays are handed to it
(compiled.py), the programs kept across processes as traced programs (programs.py)
and XLA executables (executables.py), and the seconds JAX spent compiling
(compilation.py)."""
