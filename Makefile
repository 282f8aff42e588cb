# The two set-up commands (see README): `make demo` runs the main job, `make test` the tests.
# `make wheel` builds the installable package (code + shipped models) into build/wheel/;
# `make bench` times the main job's stages on this machine (a few minutes).
.PHONY: setup demo test lint bench wheel

setup:
	bash scripts/setup.sh

demo: setup
	.venv/bin/python -m mvracklay.demo_job

# the tests in 3 workers (on 2 cores a third overlaps the tests that wait on subprocesses, streams and Ray), each
# test file on one worker (its module fixtures made once; the costly session fixtures are made once per run and
# shared: tests/conftest.py), the 10 slowest listed at the end
test: setup
	.venv/bin/python -m pytest -q -p no:cacheprovider -n 3 --dist loadfile --durations=10

lint: setup
	.venv/bin/ruff check .

bench: setup
	.venv/bin/python benchmarks/bench_infer.py --threads 2 --sizes 128 256 --checkpoint mvracklay-disc-4
	.venv/bin/python benchmarks/bench_stitch.py --sequences 2
	.venv/bin/python benchmarks/bench_long_aisle.py --frames 1000 --no-memory

# a fresh build folder each time: setuptools copies into build/lib without clearing it, so a module
# deleted since the last build would otherwise still ship
wheel: setup
	rm -rf build
	.venv/bin/python -m pip wheel . --no-deps --no-build-isolation -q -w build/wheel
	@ls -l build/wheel/*.whl
