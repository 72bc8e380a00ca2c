# All set-up happens here: a local virtual environment with every dependency, made when missing.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: serve test test-fast test-loaded shots bench results docs lint clean clean-cache venv

$(STAMP): pyproject.toml
	@test -x $(BIN)/pip || $(MAKE) --no-print-directory venv
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[fast,service,study,dev]"
	$(MAKE) --no-print-directory browser-deps
	touch $(STAMP)

# the solver's kernels compiled first, two processes sharing them (sim/apps/warm.py): else the
# first runs after a checkout or an edit of sim/ compile them, minutes counted as their solver
# time; on a warm numba cache a few seconds
serve: $(STAMP)
	$(BIN)/q3t warm --part 1/2 & $(BIN)/q3t warm --part 2/2; rc=$$?; wait $$! && [ $$rc -eq 0 ]
	$(BIN)/q3t serve

# pytest exits 5 when it collected no test: that is a failure here, never a silent pass.
pytest = $(BIN)/python -m pytest -q $(1); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "pytest collected no tests" >&2; exit 1; fi; exit $$rc

# every tier (CI): four pytest processes side by side (tests/split.py)
test: $(STAMP)
	$(BIN)/python -m tests.split

# the edit loop: tests/unit, tests/scenes and the quick modules of the other tiers (marker
# fast), without the slow tests
test-fast: $(STAMP)
	$(call pytest,-m "fast and not slow")

# the browser tests with their screenshots, to look at (runs/shots/<module>/): the suite
# itself takes none (each picture waits for software WebGL to draw)
shots: $(STAMP)
	Q3T_SHOTS=$(CURDIR)/runs/shots $(call pytest,$(wildcard tests/service/test_*browser*.py))

# The suite beside one busy process per core: a test that races the clock fails here.
# ARGS picks tests (e.g. make test-loaded ARGS=tests/apps/test_sweep.py); tests/loaded.py says
# more.
test-loaded: $(STAMP)
	$(BIN)/python -m tests.loaded $(ARGS)

bench: $(STAMP)
	$(BIN)/q3t bench

# Every measured table in docs/results/, each written and stamped (commit, date, CPU, load,
# command) by the command that measures it (docs/results/README.md lists them). One after the
# other, never side by side: they measure time. About 35 min on the 2-core machine, most of it
# the forming bench, plus the forming, springback and Fig. 4 sweeps (docs/results/README.md).
# The CalculiX comparison needs Debian's calculix-ccx: without ccx it is skipped with a message
# (`q3t bench --cases calculix` itself exits 2 then) and the other tables are still made.
R := docs/results
# the AA5754 cup's Q3T tables were of its structured disk blank (the scene's until 2026-12-07)
AA_DISK := --set mesh.kind=disk --set mesh.r_outer=0.03
# the von Mises cup drawn 30 mm deep, as the split-ring runs have it
CUP30 := --set 'tools.0.velocity=[0,0,-0.03]' --set stepping.steps=60
# the square cup to NUMISHEET'93's first stroke (15 mm), and its aluminium sheet (placed on the
# 0.81 mm sheet's skins): docs/outlines.md
SQUARE15 := --quiet --set stepping.steps=30 --set 'tools.0.velocity=[0,0,-0.015]' \
  --set 'sections.0.steps=[0,30]' --set 'sections.1.steps=[0,30]'
ALUMINIUM := --set shell.thickness=0.00081 --set material.E=71e9 --set material.nu=0.33 \
  --set material.density=2700 --set material.yield_stress=132.225264e6 \
  --set material.hardening.K=576.79e6 --set material.hardening.e0=0.01658 \
  --set material.hardening.n=0.3593 --set 'tools.0.position=[0,0,0.000405]' \
  --set 'tools.1.position=[0,0,-0.000405]' --set 'tools.2.position=[0,0,0.000405]'
# the same sheet with the DEFORM-3D manual's own inputs (its E, nu, Swift law and friction)
DEFORM_AL := --set shell.thickness=0.00081 --set material.E=70e9 --set material.nu=0.3 \
  --set material.density=2700 --set material.yield_stress=132.943258e6 \
  --set material.hardening.K=570.40e6 --set material.hardening.e0=0.01502 \
  --set material.hardening.n=0.3469 --set 'tools.0.position=[0,0,0.000405]' \
  --set 'tools.1.position=[0,0,-0.000405]' --set 'tools.2.position=[0,0,0.000405]' \
  --set tools.0.friction=0.162 --set tools.1.friction=0.162 --set tools.2.friction=0.162
# the aluminium square cup on an edge of $(1) m ($(2) mm): 15 and 40 mm, Q3T and q3t_ans
define square_cup_al
$(BIN)/q3t run square_cup --element q3t $(SQUARE15) $(ALUMINIUM) --set mesh.edge_length=$(1) --out runs/forming-square_cup-al-$(2)mm --results $(R)/forming-square_cup-aluminium-$(2)mm.md
$(BIN)/q3t run square_cup $(SQUARE15) $(ALUMINIUM) --set mesh.edge_length=$(1) --element q3t_ans --out runs/forming-square_cup-al-ans-$(2)mm --results $(R)/forming-square_cup-aluminium-ans-$(2)mm.md
$(BIN)/q3t run square_cup --element q3t --quiet $(ALUMINIUM) --set mesh.edge_length=$(1) --out runs/forming-square_cup-al-40-$(2)mm --results $(R)/forming-square_cup-aluminium-40-$(2)mm.md
$(BIN)/q3t run square_cup --quiet $(ALUMINIUM) --set mesh.edge_length=$(1) --element q3t_ans --out runs/forming-square_cup-al-40-ans-$(2)mm --results $(R)/forming-square_cup-aluminium-40-ans-$(2)mm.md
endef

results: $(STAMP)
	$(BIN)/q3t check --results $(R)/check.md
	$(BIN)/q3t bench --cases beam,cup,plastic --repeat 5 --results $(R)/bench.md
	$(BIN)/q3t bench --cases forming --repeat 3 --results $(R)/bench-forming.md
	$(BIN)/q3t mesh-tools --results $(R)/mesh-tools.md
	@if command -v ccx >/dev/null; then \
	  echo "$(BIN)/q3t bench --cases calculix --repeat 3 --results $(R)/bench-calculix.md"; \
	  $(BIN)/q3t bench --cases calculix --repeat 3 --results $(R)/bench-calculix.md; \
	else \
	  echo "skipped $(R)/bench-calculix.md: CalculiX's ccx is not installed" \
	       "(Debian: apt-get install calculix-ccx)"; \
	fi
	$(BIN)/q3t study cantilever --factorisation --levels 0.035,0.0175,0.00875,0.0046667 \
	  --out runs/fig7 --results $(R)/fig7-factorisation.md
	$(BIN)/q3t study convergence --out runs/fig8 --results $(R)/fig8-convergence.md
	$(BIN)/q3t study convergence --elements quartic --levels 0.035,0.0175,0.00875 --no-overhead \
	  --out runs/fig8-quartic --results $(R)/fig8-quartic.md
	$(BIN)/q3t study plastic_bending --overhead-only --levels 0.002 \
	  --results $(R)/overhead-plastic_bending.md
	$(BIN)/q3t study cup_blank --overhead-only --levels 0.001 --results $(R)/overhead-cup_blank.md
	$(BIN)/q3t study convergence --overhead-only --results $(R)/overhead-convergence.md
	$(BIN)/q3t study cantilever --set material.nu=0.49 --set material.E=1e11 \
	  --elements linear,q3t,quadratic --levels 0.0175,0.00875,0.0046667,0.0035 \
	  --reference quadratic:0.0046667 --no-overhead --out runs/accuracy \
	  --results $(R)/accuracy-refinement.md
	$(BIN)/q3t study cantilever --set material.nu=0 --set material.E=1e11 --elements quadratic \
	  --levels 0.0046667 --analytic euler_bernoulli --no-overhead --out runs/accuracy-eb \
	  --results $(R)/accuracy-euler-bernoulli.md
	$(BIN)/q3t study cantilever --set material.nu=0.49 --set material.E=1e11 \
	  --elements linear:1x2,linear:3x2,q3t:1x3,q3t:3x3 --levels 0.00875,0.0046667 \
	  --reference quadratic:0.0046667 --no-overhead --out runs/accuracy-quadrature \
	  --results $(R)/accuracy-quadrature.md
	$(BIN)/q3t study --course --out runs/course \
	  --results $(R)/shell-course.md
	$(BIN)/q3t study --course --scenes scordelis_lo,pinched_cylinder,pinched_hemisphere \
	  --elements quadratic --set mesh.curved=false --out runs/course-flat --results $(R)/shell-course-flat.md
	$(BIN)/q3t study --course --scenes scordelis_lo,pinched_cylinder,pinched_hemisphere \
	  --elements quadratic:3x3 --out runs/course-3x3 \
	  --results $(R)/shell-course-3x3.md
	$(BIN)/q3t study --course --elements q3t_ans --out runs/course-ans \
	  --results $(R)/shell-course-ans.md
	$(BIN)/q3t bench --cases beam,cup --elements q3t,q3t_ans --repeat 5 \
	  --results $(R)/bench-ans.md
	$(BIN)/q3t bench --cases forming --forming-elements q3t,q3t_ans --forming-edge 0.002 \
	  --repeat 7 --results $(R)/bench-forming-ans.md
	$(BIN)/q3t springback --elements q3t,quadratic,quartic --out runs/springback \
	  --results $(R)/springback-formula.md
	$(BIN)/q3t bench-service --results $(R)/service.md
	$(BIN)/q3t reference cup_drawing --element q3t --check tests/data/reference/cup_drawing-q3t-2mm.json \
	  --results $(R)/stroke-cup_drawing.md
	$(BIN)/q3t reference cup_drawing --check tests/data/reference/cup_drawing-q3t_ans-2mm.json \
	  --results $(R)/stroke-cup_drawing-ans.md
	$(BIN)/q3t run cup_drawing --quiet --out runs/forming-cup_drawing \
	  --results $(R)/forming-cup_drawing.md
	$(BIN)/q3t run cup_drawing --element q3t --quiet --set mesh.edge_length=0.0005 \
	  --out runs/forming-cup_drawing-paper --results $(R)/forming-cup_drawing-paper.md
	$(BIN)/q3t run cup_drawing_aa5754 --element q3t $(AA_DISK) --quiet --out runs/forming-cup_drawing_aa5754-2mm \
	  --results $(R)/forming-cup_drawing_aa5754-2mm.md
	$(BIN)/q3t run cup_drawing_aa5754 --element q3t_ans --quiet \
	  --results $(R)/forming-cup_drawing_aa5754-2mm-ans.md
	$(BIN)/q3t run cup_drawing_outline --quiet \
	  --results $(R)/forming-cup_drawing_outline-2mm-ans.md
	$(BIN)/q3t run cup_drawing --element q3t --quiet $(CUP30) --out runs/forming-cup_drawing-30mm-2mm \
	  --results $(R)/forming-cup_drawing-30mm-2mm.md
	$(BIN)/q3t run cup_drawing_aa5754 --element q3t $(AA_DISK) --quiet --set mesh.edge_length=0.00125 \
	  --out runs/forming-cup_drawing_aa5754 --results $(R)/forming-cup_drawing_aa5754-1.25mm.md
	$(BIN)/q3t run cup_drawing --element q3t --quiet $(CUP30) --set mesh.edge_length=0.00125 \
	  --out runs/forming-cup_drawing-30mm \
	  --results $(R)/forming-cup_drawing-30mm-1.25mm.md
	$(BIN)/q3t run cup_drawing --element q3t --quiet $(CUP30) --set mesh.edge_length=0.0008 \
	  --out runs/forming-cup_drawing-30mm-0.8mm
	$(BIN)/q3t run cup_drawing --element q3t --quiet $(CUP30) --set mesh.edge_length=0.0005 \
	  --out runs/forming-cup_drawing-30mm-0.5mm
	$(BIN)/q3t run cup_drawing --element q3t --quiet $(CUP30) --set mesh.edge_length=0.00125 \
	  --set shell.thickness_points=7 --out runs/forming-cup_drawing-30mm-7points
	$(BIN)/q3t run cup_drawing_aa5754 --element q3t $(AA_DISK) --quiet --set mesh.edge_length=0.0008 \
	  --out runs/forming-cup_drawing_aa5754-0.8mm
	$(BIN)/q3t splitring runs/forming-cup_drawing-30mm-2mm runs/forming-cup_drawing_aa5754-2mm \
	  runs/forming-cup_drawing-30mm runs/forming-cup_drawing_aa5754 \
	  runs/forming-cup_drawing-30mm-0.8mm runs/forming-cup_drawing_aa5754-0.8mm \
	  --heights 6,11 --heights 8,13 --heights 12,17 --results $(R)/split-ring.md
	$(BIN)/q3t splitring runs/forming-cup_drawing-30mm runs/forming-cup_drawing_aa5754 \
	  runs/forming-cup_drawing-30mm-0.8mm runs/forming-cup_drawing_aa5754-0.8mm \
	  --heights 8,13 --cut-angle 45 --results $(R)/split-ring-cut45.md
	$(BIN)/q3t splitring runs/forming-cup_drawing-30mm-2mm runs/forming-cup_drawing-30mm \
	  runs/forming-cup_drawing-30mm-7points runs/forming-cup_drawing-30mm-0.8mm \
	  runs/forming-cup_drawing-30mm-0.5mm \
	  --heights 6,11 --heights 8,13 --heights 12,17 --results $(R)/split-ring-refinement.md
	$(BIN)/q3t run square_cup --element q3t $(SQUARE15) --out runs/forming-square_cup \
	  --results $(R)/forming-square_cup.md
	$(BIN)/q3t run square_cup --element q3t $(SQUARE15) $(ALUMINIUM) --out runs/forming-square_cup-al \
	  --results $(R)/forming-square_cup-aluminium.md
	$(BIN)/q3t run square_cup --element q3t --quiet --out runs/forming-square_cup-40 \
	  --results $(R)/forming-square_cup-40.md
	$(BIN)/q3t run square_cup --element q3t --quiet $(ALUMINIUM) --out runs/forming-square_cup-al-40 \
	  --results $(R)/forming-square_cup-aluminium-40.md
	$(BIN)/q3t run square_cup --element q3t $(SQUARE15) $(DEFORM_AL) \
	  --out runs/forming-square_cup-deform --results $(R)/forming-square_cup-aluminium-deform.md
	$(BIN)/q3t run square_cup --element q3t --quiet $(DEFORM_AL) \
	  --out runs/forming-square_cup-deform-40 \
	  --results $(R)/forming-square_cup-aluminium-deform-40.md
	$(call square_cup_al,0.0025,2.5)
	$(call square_cup_al,0.00125,1.25)
	$(BIN)/q3t run square_cup $(SQUARE15) $(ALUMINIUM) --element q3t_ans \
	  --out runs/forming-square_cup-al-ans --results $(R)/forming-square_cup-aluminium-ans.md
	$(BIN)/q3t sweep cup_drawing --grid mesh.edge_length=0.004,0.003,0.0025,0.002 --set shell.element=q3t \
	  --out runs/forming-cup_mesh --results $(R)/forming-cup_mesh.md
	$(BIN)/q3t sweep cup_drawing --grid shell.element=linear,q3t --set mesh.edge_length=0.003 \
	  --out runs/forming-cup_elements --results $(R)/forming-cup_elements.md
	$(BIN)/q3t sweep cup_drawing --grid shell.element=q3t,q3t_ans,quadratic \
	  --out runs/forming-cup_elements-2mm --results $(R)/forming-cup_elements-2mm.md
	$(BIN)/q3t sweep beam_forming --grid shell.element=linear,q3t,quadratic --ratio curvature \
	  --out runs/forming-beam_forming --results $(R)/forming-beam_forming.md
	$(BIN)/q3t sweep cookie_cutter --grid shell.element=linear,q3t --set mesh.edge_length=0.003 \
	  --out runs/forming-cookie_cutter --results $(R)/forming-cookie_cutter.md
	$(BIN)/q3t sweep plastic_bending --grid shell.element=linear,q3t,quadratic,quartic \
	  --ratio curvature --budget 1800 --out runs/springback-plastic_bending \
	  --results $(R)/springback-plastic_bending.md
	$(BIN)/q3t sweep stretch_plate --grid shell.element=linear,q3t --grid mesh.imperfection=0,1e-4 \
	  --grid 'loads.0.vector=[1e4,0,0],[1e5,0,0],[3e5,0,0]' --set material.nu=0.499 \
	  --set mesh.edge_length=0.035 --out runs/fig4 --results $(R)/fig4.md
	$(BIN)/q3t bifurcation stretch_wrinkling --elements quadratic,q3t,linear --spacing 0.0025 \
	  --results $(R)/fig4-wrinkling.md
	$(BIN)/q3t bifurcation stretch_wrinkling --elements q3t_ans --spacing 0.0025 \
	  --results $(R)/fig4-wrinkling-ans.md
	$(BIN)/q3t bifurcation stretch_wrinkling --elements q3t_ans --spacing 0.00175 \
	  --results $(R)/fig4-wrinkling-ans-1.75mm.md
	$(BIN)/q3t bifurcation stretch_wrinkling --elements quadratic --spacing 0.00175 \
	  --results $(R)/fig4-wrinkling-quadratic-3.5mm.md
	$(BIN)/q3t bifurcation stretch_wrinkling --elements quadratic --spacing 0.00125 \
	  --results $(R)/fig4-wrinkling-quadratic-2.5mm.md
	# the reference at 1.75 mm (nodes 0.875 mm apart, 295,000 DoFs) to 10 % only: 21 min
	$(BIN)/q3t bifurcation stretch_wrinkling --elements quadratic --spacing 0.000875 \
	  --set 'bcs.1.displacement=[0.025,0.0,0.0]' --set stepping.steps=5 \
	  --results $(R)/fig4-wrinkling-quadratic-1.75mm.md
	$(BIN)/q3t bifurcation stretch_plate --elements quadratic,q3t,linear --spacing 0.0175 \
	  --set material.nu=0.499 --set 'loads.0.vector=[3e5,0,0]' --set stepping.steps=10 \
	  --results $(R)/fig4-plate.md

# the scene field reference, rendered from the schema (tests/unit/test_docs.py fails when it is
# stale)
docs: $(STAMP)
	$(BIN)/python -m sim.scene_reference docs/scene-reference.md

lint: $(STAMP)
	$(BIN)/ruff check sim server tests

clean:
	rm -rf $(VENV) runs .numba-cache

# numba's compiled kernels (cache=True): sim/__init__.py keys the folder on a hash of sim's
# sources, so this is only needed to measure a cold start by hand
clean-cache:
	rm -rf .numba-cache
	find sim server -name '*.nbi' -delete -o -name '*.nbc' -delete

# Browser tests drive Debian's chromium through Playwright (never `playwright install`).
.PHONY: browser-deps
browser-deps:
	@if [ ! -x /usr/bin/chromium ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    apt-get update -qq && apt-get install -y -qq chromium; \
	  else echo "browser tests will skip: /usr/bin/chromium missing (as root: apt-get install chromium)"; fi; \
	fi
	@$(BIN)/python -c "import playwright" 2>/dev/null || $(BIN)/pip install -q playwright
	@$(MAKE) --no-print-directory gmsh-deps

# gmsh's wheel (outline blanks) links X and OpenGL libraries even when it meshes headless:
# Debian's chromium brings some of them, not these.
GMSH_DEBS := libgl1 libglu1-mesa libgomp1 libxcursor1 libxft2 libxinerama1
.PHONY: gmsh-deps
gmsh-deps:
	@$(BIN)/python -c "import gmsh" 2>/dev/null || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    apt-get update -qq && apt-get install -y -qq $(GMSH_DEBS); \
	  else echo "outline blanks need gmsh's libraries (as root: apt-get install $(GMSH_DEBS))"; \
	  fi; }

# Debian's python3 makes a venv only with the python3-venv package (ensurepip); as root we
# install it, otherwise we say what to run. A failed attempt leaves a .venv without pip: removed.
venv:
	@$(PY) -m venv $(VENV) || { \
	  rm -rf $(VENV); \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "$(PY) -m venv failed: installing Debian's python3-venv"; \
	    apt-get update -qq && apt-get install -y -qq python3-venv && $(PY) -m venv $(VENV); \
	  else \
	    echo "$(PY) -m venv failed: install python3-venv (Debian, as root:" \
	         "apt-get install python3-venv) or set PY to a Python 3.11 with venv, then" \
	         "run make again" >&2; \
	    exit 1; \
	  fi; }
	@test -x $(BIN)/pip || { echo "$(VENV) has no pip after creation" >&2; exit 1; }
