# Thin entry points: each target calls one script or one tool.
# make bench runs every speed benchmark (ops-bench all); make bench PARTS="physics bridge" names some.
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
	bash -c 'source setup.bash && ops-bench all $(PARTS)'

lint: setup
	bash -c 'source setup.bash && ruff check . && ruff format --check .'

figures: setup
	bash -c 'source setup.bash && ops-bench figures physics'
