.PHONY: install test demo bench clean-cache

install:
	python3 -m pip install -e ".[test]"

test:
	python3 -m pytest

demo:
	rayaccel demo

bench:
	python3 benchmarks/bench_structures.py
	python3 benchmarks/bench_lecture.py

# Numba's cache does not notice edits to a kernel's callees in other files:
# clear it after changing kernels.
clean-cache:
	find src -name '*.nbi' -delete -o -name '*.nbc' -delete
