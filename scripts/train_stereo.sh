#!/bin/sh
# How the stereo-evidence VoRTX try of issue 11 (deliverable 4) was run. Run from the repository root
# with the project venv; CPU only, on the shared 2-core machine (load average 12-15 during the run,
# so wall times are several times the CPU times). Rooms live outside the repository.
set -eu
PY=.venv/bin/python
D=/work/data/stereo11

# 1. Rooms with plain painted walls/ceilings and dark or glossy furniture ("mixed" surfaces),
#    Workbench, 160x120, 40 frames. Training seeds 2000-2023, held out 3000-3005.
S="--frames 40 --resolution 160x120 --renderer workbench --surfaces mixed --quiet"
$PY -m engine synth --rooms 12 --out $D/train --seed 2000 $S &
$PY -m engine synth --rooms 12 --out $D/train --seed 2012 $S &
wait
$PY -m engine synth --rooms 3 --out $D/heldout --seed 3000 $S &
$PY -m engine synth --rooms 3 --out $D/heldout --seed 3003 $S &
wait

# 2. Plane-sweep stereo of every other frame of each training room, from the rendered photos
#    (default reconstruction options), cached as <room>/stereo_depth.npz. The trainer computes a
#    missing cache itself; this fills them in parallel beforehand.
$PY -m engine.train.room_stereo $D/train --shard 0/2 &
$PY -m engine.train.room_stereo $D/train --shard 1/2 &
wait

# 3. Train the evidence model (configs/train_stereo.json: rooms 2000-2007, masked-mean pooling,
#    frozen ImageNet trunk, lr 3e-4, 28-minute time box). It starts as classical fusion: every
#    level's head is a residual on the fused stereo TSDF with a zero last layer.
$PY -m engine train configs/train_stereo.json --no-progress > $D/runs/train_stereo.log 2>&1

# 4. Held-out rooms: classical stereo fusion and the room box, and the trained evidence model.
EVAL="--image-size 128 --views 12 --frustum-depth 3.0 --max-room-size 7 7 3.5"
$PY -m engine eval-weights --rooms $D/heldout --weights "stereo fusion=stereo" --out $D/eval_stereo $EVAL
$PY -m engine eval-weights --rooms $D/heldout --no-box --out $D/eval_evidence $EVAL \
    --weights "VoRTX-evidence=$D/runs/vortx_stereo/weights.safetensors"
