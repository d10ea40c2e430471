.PHONY: install test demo bench

install:
	python3 -m pip install -e ".[test]"

test:
	python3 -m pytest

demo:
	rayaccel demo

bench:
	python3 benchmarks/bench_grid.py
	python3 benchmarks/bench_lecture.py
