# The two commands a user needs: `make demo` and `make test`. Both build .venv on first use.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-$(shell cat requirements.txt constraints.txt | sha1sum | cut -c1-12)

.PHONY: venv tools test demo extension bench bench-real real-rooms devrooms clean

venv: $(STAMP)

# The JavaScript tools of the textured result (tools/package.json, exact versions in package-lock.json):
# the Khronos glTF-Validator (tests), the Basis Universal encoder (KTX2 textures of the headset presets),
# model-viewer and three.js's decoders (the preview page). Needs node and npm; without them the KTX2
# presets and the preview say what to install, and the tests that need them skip.
TOOLS_STAMP := tools/node_modules/.installed-$(shell cat tools/package-lock.json 2>/dev/null | sha1sum | cut -c1-12)

tools: $(TOOLS_STAMP)

$(TOOLS_STAMP): tools/package.json tools/package-lock.json
	@command -v npm >/dev/null || { echo "warning: npm not found: KTX2 textures, the preview page and the glTF-Validator tests need node and npm (e.g. apt-get install nodejs npm), then make tools"; exit 0; }
	cd tools && npm ci --ignore-scripts --no-audit --no-fund --loglevel=error
	rm -f tools/node_modules/.installed-*
	touch $(TOOLS_STAMP)

$(STAMP): requirements.txt constraints.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found. Install Python 3.11 (Blender's bpy module needs exactly 3.11) or run 'make PYTHON=/path/to/python3.11'."; exit 1; }
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || { echo "error: $(PYTHON) is not Python 3.11; bpy 5.0 needs 3.11."; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt -c constraints.txt
	rm -f $(VENV)/.installed-*
	touch $(STAMP)

test: venv tools
	$(PY) -m pytest -q -p no:cacheprovider -n 2 --dist loadfile

demo: venv
	$(PY) scripts/demo.py

# The installable zip (dist/vortx-<version>.zip), built by Blender's own extension builder.
extension: venv
	$(PY) scripts/build_extension.py --output-dir dist

bench: venv
	$(PY) -m engine bench

# The real-room suite (engine/eval/real_rooms.py): every real capture with truth under DATA, every
# default, scored beside the committed docs/real_rooms.json; about 30 min on 2 cores. `make real-rooms`
# fetches the captures first (research data under their own licences, kept outside the repository).
DATA ?= $(abspath ../data)
real-rooms: venv
	$(PY) scripts/fetch_real_rooms.py $(DATA)

bench-real: venv
	$(PY) -m engine bench --real $(DATA) --out docs/real_rooms.json

# The fixed held-out development rooms (MODEL.md "Development rooms"): seeds 5001-5004 clean and
# real, outside the repository. Re-running resumes; about 1-2 min per Workbench room and 30 min per
# Cycles room on 2 busy cores.
DEVROOMS ?= $(abspath ../devrooms)
devrooms: venv
	nice -n 10 $(PY) -m engine synth --heldout-set clean --out $(DEVROOMS)/clean
	nice -n 10 $(PY) -m engine synth --heldout-set realistic --out $(DEVROOMS)/realistic

clean:
	rm -rf out dist
