# Two commands a user needs: `make demo` (the main job) and `make test` (the whole test suite).
# Both create .venv and install everything on first use.
PYTHON ?= python3
VENV ?= .venv
# Choose your own torch build, e.g. `make test TORCH=torch` or a CUDA wheel; the default is the CPU
# build pinned so that nothing pulls CUDA packages on a CPU machine.
TORCH ?= torch==2.13.0
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test docs bench lint clean wheel

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	$(BIN)/pip install "$(TORCH)"
	$(BIN)/pip install -e ".[test,docs]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/defocus demo --out runs/demo --overwrite

test: $(STAMP)
	$(BIN)/ruff check optics models datasets defocus tests benchmarks examples
	$(BIN)/python -m pytest -q --durations=15
	$(BIN)/mkdocs build --strict --site-dir build/site
	$(BIN)/python docs/check_site.py build/site

# The package as users install it: a wheel, installed into a new virtual environment (outside
# the source tree, so nothing is imported from the checkout), whose command line then runs.
wheel: $(STAMP)
	rm -rf dist build/wheel-venv
	$(BIN)/pip install --quiet build
	$(BIN)/python -m build --wheel --outdir dist .
	$(PYTHON) -m venv build/wheel-venv
	build/wheel-venv/bin/pip install --quiet "$(TORCH)"
	build/wheel-venv/bin/pip install --quiet dist/*.whl
	cd build && wheel-venv/bin/defocus --help > /dev/null && wheel-venv/bin/python -m defocus --version

docs: $(STAMP)
	$(BIN)/mkdocs serve

bench: $(STAMP)
	$(BIN)/python benchmarks/render.py

clean:
	rm -rf $(VENV) build dist runs .pytest_cache
