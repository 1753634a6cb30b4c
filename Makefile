# The two commands a user needs: `make demo` and `make test`. Both build .venv on first use.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-$(shell cat requirements.txt constraints.txt | sha1sum | cut -c1-12)

.PHONY: venv test demo extension bench clean

venv: $(STAMP)

$(STAMP): requirements.txt constraints.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found. Install Python 3.11 (Blender's bpy module needs exactly 3.11) or run 'make PYTHON=/path/to/python3.11'."; exit 1; }
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || { echo "error: $(PYTHON) is not Python 3.11; bpy 5.0 needs 3.11."; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt -c constraints.txt
	rm -f $(VENV)/.installed-*
	touch $(STAMP)

test: venv
	$(PY) -m pytest -q -p no:cacheprovider

demo: venv
	$(PY) scripts/demo.py

# The installable zip (dist/vortx-<version>.zip), built by Blender's own extension builder.
extension: venv
	$(PY) scripts/build_extension.py --output-dir dist

bench: venv
	$(PY) -m engine bench

clean:
	rm -rf out dist
