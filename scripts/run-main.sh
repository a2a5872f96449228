#!/usr/bin/env bash
# The main job on the built-in simulated rig: installs what is missing, builds, simulates a candle
# filmed by the two-camera rig of config/sim_rig.yaml (camera models, calibration board views, fire
# images and ground truth), records the calibration board with the capture daemon and calibrates
# the rig from that recording (mrcal), records 2 s of the fire and exports the recording, renders
# the ground truth back through the rig's cameras, reconstructs frame 0 by tomography with the
# calibrated rig and fits its temperature, density and exposure (with a report).
# Output in runs/sim (override with FLAMERIG_RUN_DIR); open runs/sim/preview.png first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
RUN_DIR="${FLAMERIG_RUN_DIR:-runs/sim}"
BIN="${FLAMERIG_BUILD_DIR:-build}/tools/flamerig"
case "$BIN" in /*) ;; *) BIN="$PWD/$BIN" ;; esac
"$BIN" simulate --config config/sim_rig.yaml --out "$RUN_DIR"
# Calibration: the sim cameras replay the board views (a board waved in front of the rig; a camera
# that does not see it shows a dark frame) at 10 Hz into a recording, which `calibrate` turns into
# a rig (the ring frame put at the candle's base, config/calibrate_sim.yaml).
VIEWS=$(find "$RUN_DIR/calibration" -mindepth 1 -maxdepth 1 -type d | wc -l)
cat > "$RUN_DIR/capture_calibration.yaml" <<EOF
data_dir: recordings
sync: hardware-trigger
trigger_rate_hz: 10
pretrigger_seconds: 0
cameras:
  - {name: cam0, width: 320, height: 240, pixel_format: Mono8, sim: {replay: ., replay_content: calibration}}
  - {name: cam1, width: 320, height: 240, pixel_format: Mono8, sim: {replay: ., replay_content: calibration}}
EOF
rm -rf "$RUN_DIR/recordings/calibration"
(cd "$RUN_DIR" && "$BIN" capture --config capture_calibration.yaml --record calibration \
  --duration "$(( VIEWS / 10 + 2 ))")
"$BIN" calibrate --recording "$RUN_DIR/recordings/calibration" \
  --board "$RUN_DIR/calibration/board.yaml" --config config/calibrate_sim.yaml \
  --out "$RUN_DIR/calibrated"
# The capture daemon on the simulated rig: two sim cameras on a hardware trigger line replay the
# dataset's images (frames/) for 2 s into a lossless recording, which is then exported as PNG sets.
cat > "$RUN_DIR/capture.yaml" <<EOF
data_dir: recordings
sync: hardware-trigger
trigger_rate_hz: 30
pretrigger_seconds: 0
cameras:
  - {name: cam0, width: 320, height: 240, pixel_format: RGB8, sim: {replay: .}}
  - {name: cam1, width: 320, height: 240, pixel_format: RGB8, sim: {replay: .}}
EOF
rm -rf "$RUN_DIR/recordings/take"
(cd "$RUN_DIR" && "$BIN" capture --config capture.yaml --record take --duration 2)
"$BIN" export --recording "$RUN_DIR/recordings/take" --out "$RUN_DIR/recorded"
"$BIN" render --rig "$RUN_DIR/rig.yaml" --volume "$RUN_DIR/truth/frame_000000.vdb" --out "$RUN_DIR/rendered"
# The cameras' exposure is a capture setting, not part of the calibration: the dataset's.
EXPOSURE=$(sed -n 's/^  exposure: //p' "$RUN_DIR/dataset.yaml")
"$BIN" reconstruct --rig "$RUN_DIR/calibrated/rig.yaml" --images "$RUN_DIR/frames/frame_000000" \
  --exposure "$EXPOSURE" \
  --out "$RUN_DIR/reconstruction/frame_000000.vdb" --truth "$RUN_DIR/truth/frame_000000.vdb" \
  --cache "$RUN_DIR/cache" --preview "$RUN_DIR/reconstruction/preview.png"
"$BIN" fit --rig "$RUN_DIR/calibrated/rig.yaml" --images "$RUN_DIR/frames/frame_000000" \
  --tomography "$RUN_DIR/reconstruction/frame_000000.vdb" --out "$RUN_DIR/fit/frame_000000.vdb" \
  --truth "$RUN_DIR/truth/frame_000000.vdb"
echo
echo "main job done: dataset in $RUN_DIR (preview.png, frames/, calibration/, truth/*.vdb, rig.yaml);"
echo "the ground truth re-rendered through the rig is in $RUN_DIR/rendered; the tomography of frame 0"
echo "(emission volume and a preview of input against reconstruction) is in $RUN_DIR/reconstruction;"
echo "the fitted temperature and density of frame 0 are in $RUN_DIR/fit (report: fit/frame_000000_report/report.md);"
echo "the rig calibrated from the recorded board views is in $RUN_DIR/calibrated (report.md, rig_top.png);"
echo "the capture daemon's recording is in $RUN_DIR/recordings/take, exported to $RUN_DIR/recorded."
