"""A run's start-up: everything between the command and the first training epoch that is not the algorithm.

``session`` and ``compiled`` are the face the rest of training sees: ``session.StartUp`` (begun before jax's
backend starts, opened once the run's record exists) and ``compiled.compile_programs``, the one call a
trainer makes, its programs in and compiled out (``CompiledPrograms``, which also ends the start-up).
Behind them: ``backend_env`` sets the environment jax and torch read when their backends start;
``compile_cache`` configures jax's persistent compile cache; ``compiler`` compiles the programs ahead of
time, concurrently, and says what is compiling; ``executable_cache`` (keyed by ``executable_key``) loads a
warm run's executables instead of tracing them; ``autotune`` seeds XLA's GPU autotune cache from the shipped
results; ``breakdown`` records where the start-up's seconds went.
"""
