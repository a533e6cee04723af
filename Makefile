# The two commands of the README: `make demo` and `make test`. Both bootstrap
# .venv (and the system GL libraries MuJoCo rendering needs) on first use, as does
# `make research-test`, the finished studies' tests (research/tests; `make test` leaves
# them out: pyproject.toml's testpaths is tests/ alone).
PY       ?= python3
VENV     := .venv
VPY      := $(VENV)/bin/python
STAMP    := $(VENV)/.installed
export MUJOCO_GL ?= egl

.PHONY: demo test research-test bench venv gl clean

$(STAMP): pyproject.toml constraints.txt
	@test -x $(VPY) || $(PY) -m venv $(VENV)
	$(VPY) -m pip install --quiet --upgrade pip
	$(VPY) -m pip install --quiet -c constraints.txt -e '.[test,ray,gym,view,formats,lerobot]'
	@touch $(STAMP)

venv: $(STAMP)

gl:
	@bash scripts/ensure_gl.sh

demo: $(STAMP) gl
	$(VENV)/bin/sebvs demo topologies/nav_policy.toml --swap-to event --swap-after 150

test: $(STAMP) gl
	$(VPY) -m pytest -q

research-test: $(STAMP) gl
	$(VPY) -m pytest -q research/tests

bench: $(STAMP) gl
	$(VPY) tools/bench/bench_hops.py --quick --json out/bench_hops.json
	$(VPY) tools/bench/bench_hop_cpu.py --quick --json out/bench_hop_cpu.json

clean:
	rm -rf $(VENV) runs out
