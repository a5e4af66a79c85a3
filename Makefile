# Thin entry points: each target calls one script.
.PHONY: setup demo demo-rig test bench lint figures

setup:
	bash scripts/setup.sh

demo: setup
	bash scripts/demo.sh

demo-rig: setup
	bash scripts/demo_rig.sh

test: setup
	bash scripts/test.sh

bench: setup
	bash scripts/bench.sh

lint: setup
	bash -c 'source setup.bash && ruff check . && ruff format --check .'

figures: setup
	bash -c 'source setup.bash && python scripts/make_physics_figures.py'
