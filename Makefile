# Two commands on a fresh machine: `make dataset` (the mini data set) and `make test`.
# Everything runs inside .venv, which the first target that needs it creates.

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup assets dataset tables targeting test bench clean-assets

setup: $(STAMP)

# pip byte-compiles the packages one file at a time; compileall does it on every core (the venv step x0.79,
# paired runs, issue 36)
$(STAMP): requirements.txt pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet --no-compile -r requirements.txt
	$(PY) -c "import compileall, sysconfig; compileall.compile_dir(sysconfig.get_paths()['purelib'], quiet=2, workers=0)"
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

assets: setup
	$(PY) -m syneepose assets

DATA ?= data/mini

dataset: assets
	$(PY) -m syneepose dataset --preset mini --out $(DATA)

# The paper's tables on $(DATA): the ablation variants, depth alignment, and the K_r / K_f sweeps.
# A failing run fails the target (`|| exit 1`: a shell loop alone reports only its last command).
RESULTS ?= results/mini
RUN := $(PY) -m eval.run --method feepe --dataset $(DATA)

tables: dataset
	for v in A B C D; do $(RUN) --variant $$v --out $(RESULTS)/feepe-$$v || exit 1; done
	$(RUN) --icp --out $(RESULTS)/feepe-D-icp
	for k in 1 3 10; do $(RUN) --k-r $$k --out $(RESULTS)/feepe-kr$$k || exit 1; done
	for k in 2 4 16; do $(RUN) --k-f $$k --out $(RESULTS)/feepe-kf$$k || exit 1; done
	$(PY) -m eval.run --method ppf --dataset $(DATA) --out $(RESULTS)/ppf
	$(PY) -m eval.tables $(RESULTS)/feepe-* $(RESULTS)/ppf --out $(RESULTS)/tables
	$(PY) -m eval.report $(RESULTS)/feepe-* $(RESULTS)/ppf --out $(RESULTS)/report

# The targeting experiment: the same segments rendered with and without a ChArUco board on the flange,
# marker hand-eye against FEEPE (with the mini templates) at 3-20 views; table and plot in results/targeting.
# targeting-stations: the fair marker peer (stations where the board is seen in every view).
AIM_ROBOTS ?= panda+panda_hand,ur5e+robotiq_2f85,panda+robotiq_3f
AIM := $(PY) -m eval.targeting --marker data/targeting-marker --plain data/targeting-plain --templates-dir $(DATA)/templates
FAIR := $(PY) -m eval.targeting --marker data/stations-marker --plain data/stations-plain --templates-dir $(DATA)/templates

targeting: dataset
	$(PY) -m syneepose render --preset targeting --robots $(AIM_ROBOTS) --marker --out data/targeting-marker
	$(PY) -m syneepose render --preset targeting --robots $(AIM_ROBOTS) --out data/targeting-plain
	$(AIM) --out results/targeting/feepe-D
	$(AIM) --icp --out results/targeting/feepe-D-icp
	$(PY) -m syneepose render --preset targeting-stations --robots $(AIM_ROBOTS) --marker --out data/stations-marker
	$(PY) -m syneepose render --preset targeting-stations --robots $(AIM_ROBOTS) --out data/stations-plain
	$(FAIR) --out results/targeting/stations-feepe-D
	$(FAIR) --refine silhouette --silhouette robot --out results/targeting/stations-robot-sil
	$(FAIR) --refine silhouette --silhouette robot --mask-noise sam --out results/targeting/stations-robot-sil-sam
	$(PY) -m eval.tables results/targeting/feepe-D results/targeting/feepe-D-icp results/targeting/stations-* \
		--out results/targeting/tables

# The report test opens a page in headless Chromium (CI runs as root on Debian).
test: assets
	command -v chromium >/dev/null || (apt-get update && apt-get install -y --no-install-recommends chromium)
	$(PY) -m pytest -x -q

bench: dataset
	$(PY) benchmarks/assets_build.py
	$(PY) benchmarks/render.py
	$(PY) benchmarks/render_profile.py
	$(PY) benchmarks/stereo_cost.py --pathtraced
	$(PY) benchmarks/ray_scaling.py
	$(PY) benchmarks/templates.py
	$(PY) benchmarks/estimator.py --dataset $(DATA)
	$(PY) benchmarks/estimator.py --dataset $(DATA) --refine silhouette
	$(PY) benchmarks/estimator.py --dataset $(DATA) --refine silhouette --silhouette robot
	$(PY) benchmarks/estimator.py --dataset $(DATA) --refine silhouette+depth
	$(PY) benchmarks/estimator.py --dataset $(DATA) --refine silhouette+depth --silhouette robot
	$(PY) benchmarks/estimator.py --dataset $(DATA) --masks none
	$(PY) benchmarks/silhouette.py --dataset $(DATA)
	$(PY) benchmarks/metrics.py

clean-assets:
	rm -rf assets
