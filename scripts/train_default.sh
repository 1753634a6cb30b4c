#!/bin/sh
# How the shipped default weights (weights/vortx-default.safetensors + .json) were produced.
# Run from the repository root with the project venv. CPU only; every number below is what was used.
# Wall clock on the 2-core shared build machine: ~4 min rendering (two synth processes), 60 min
# training (both models in parallel, one thread each), ~20 min held-out evaluation. Results: MODEL.md.
set -eu
PY=.venv/bin/python
mkdir -p runs

# 1. Synthetic rooms with Blender (Workbench with procedural textures, 160x120, 40 frames per room).
#    Training rooms: seeds 0..63. Held-out rooms: seeds 1000..1007 (never used for training).
#    Each room gets mesh_gt.ply and its 4 cm ground-truth TSDF (tsdf_gt.npz) from the renderer.
SYNTH="--frames 40 --resolution 160x120 --renderer workbench --quiet"
$PY -m engine synth --rooms 32 --out data/synth/train   --seed 0    $SYNTH &
$PY -m engine synth --rooms 32 --out data/synth/train   --seed 32   $SYNTH &
wait
$PY -m engine synth --rooms 4  --out data/synth/heldout --seed 1000 $SYNTH &
$PY -m engine synth --rooms 4  --out data/synth/heldout --seed 1004 $SYNTH &
wait

# 2. VoRTX (transformer fusion + projective occupancy) and the averaging ablation on the same rooms,
#    same crops (same seed), same steps: phase 1 2800 steps (mean pooling, frozen trunk, lr 1e-3) +
#    phase 2 1100 steps (projective-occupancy pooling, trunk unfrozen except BatchNorm, lr 3e-4),
#    batch 2, 6 views, 128x96 images, 48x48x24 crops, class-balanced occupancy BCE.
$PY -m engine train configs/train_default.json --no-progress > runs/train_default.log 2>&1 &
$PY -m engine train configs/train_average.json --no-progress > runs/train_average.log 2>&1 &
wait

# 3. Both models with both inference rules for the 3D CNN's BatchNorm (the scene's own statistics,
#    `sparse_norm_statistics: "scene"`, shipped; and the running averages from training; MODEL.md),
#    evaluated on the held-out rooms: Atlas metrics vs mesh_gt.ply trimmed to observed voxels, depth
#    metrics, and the room-box floor. (In the actual run each model's evaluation was a separate
#    process, VoRTX's split over two by rooms; same settings.)
for n in vortx_default average_default; do
  $PY -c "from pathlib import Path; from engine.train.evaluate import ship_weights; \
ship_weights(Path('runs/$n/weights.safetensors'), Path('runs/$n/weights_scene.safetensors'), half=False, \
config_changes={'sparse_norm_statistics': 'scene'})"
done
EVAL="--image-size 128 --views 12 --frustum-depth 3.0 --max-room-size 7 7 3.5"
$PY -m engine.train.evaluate --rooms data/synth/heldout --out runs/eval_default $EVAL \
    --weights "VoRTX=runs/vortx_default/weights_scene.safetensors" "averaging=runs/average_default/weights_scene.safetensors" \
              "VoRTX-running=runs/vortx_default/weights.safetensors" "averaging-running=runs/average_default/weights.safetensors"
# The picture: VoRTX, averaging, ground truth; ceilings clipped 0.3 m below the room's height.
$PY -c "import json; from pathlib import Path; from engine.train.evaluate import render_side_by_side as r; from engine.mesh_io import read_ply; \
room = Path('data/synth/heldout/room_01000'); h = json.loads((room / 'room.json').read_text())['dims'][2]; \
r([read_ply('runs/eval_default/room_01000_VoRTX.ply'), read_ply('runs/eval_default/room_01000_averaging.ply'), \
   read_ply(room / 'mesh_gt.ply')], ['VoRTX (held-out room_01000)', 'averaging ablation', 'ground truth'], \
   Path('docs/model_reconstruction.png'), size=(288, 216), clip_above=h - 0.3)"

# 4. Ship the VoRTX weights (float16 storage, loads into float32) where engine.model.weights.DEFAULT_WEIGHTS
#    points, with scene statistics: fewer points on the synthetic F-score than the running averages,
#    better depth and accuracy, and the only one of the two that gives a surface on real photos (step 5).
$PY -c "from pathlib import Path; from engine.train.evaluate import ship_weights; \
ship_weights(Path('runs/vortx_default/weights.safetensors'), Path('weights/vortx-default.safetensors'), \
config_changes={'sparse_norm_statistics': 'scene'})"

# 5. Real photos (no ground truth): poses and reconstruction of the fox capture, and the picture.
$PY -m engine poses ../shared/data/fox/images --out /tmp/fox
$PY -m engine reconstruct /tmp/fox --method vortx --out /tmp/fox.ply
$PY scripts/capture_view_picture.py /tmp/fox /tmp/fox.ply --frame 0018 --out docs/fox_reconstruction.png
#    The same with the running averages, for MODEL.md's comparison (not shipped).
$PY -m engine reconstruct /tmp/fox --method vortx --out /tmp/fox_running.ply --weights runs/vortx_default/weights.safetensors
