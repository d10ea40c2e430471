.PHONY: install test demo bench clean-cache

install:
	python3 -m pip install -e ".[test]"

test:
	python3 -m pytest -n auto --dist loadfile

demo:
	rayaccel demo

bench:
	python3 benchmarks/bench_structures.py
	python3 benchmarks/bench_lecture.py

# Empty Numba's cache (edits to kernels and their callees are noticed without it: src/rayaccel/_cache_key.py).
clean-cache:
	find src -name '*.nbi' -delete -o -name '*.nbc' -delete
