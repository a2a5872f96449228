#!/usr/bin/env bash
# The main job on the built-in simulated rig, from nothing: installs what is missing, builds, and
# tells the whole story on simulated hardware:
#   1. simulate: a flickering candle (12 frames) and a ChArUco board, as the two cameras of
#      config/sim_rig.yaml would see them, with the ground truth;
#   2. the capture daemon records the board waved in front of the simulated cameras, and
#      `flamerig calibrate` builds the rig from that recording (mrcal); `flamerig
#      calibrate-radiometry` fits each camera's gains from a black-body calibrator's shots and
#      keeps the exposure time that exposure 1 stands for;
#   3. the capture daemon records the burning fire (the sim cameras replay the dataset on a
#      hardware trigger line, as Bayer mosaics), and `flamerig export` writes the recording as
#      PNG frame sets;
#   4. `flamerig run` reconstructs and fits every recorded frame set through the calibrated rig,
#      at the exposure the cameras' recorded settings give over the calibrated unit (the
#      simulator's, printed beside it), warm-starting each frame from the one before, and writes
#      the volumes, a Blender-ready
#      sequence and a report with the error against the known truth; then again with one
#      temperature and density per ring about the flame's axis (`run --axisymmetric`), and both
#      scored against the truth beside a constant temperature;
#   5. `flamerig render --scene` lights a small still life with the first fitted frame.
# Output in runs/sim (override with FLAMERIG_RUN_DIR); open runs/sim/run/report/index.html.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
RUN_DIR="${FLAMERIG_RUN_DIR:-runs/sim}"
BIN="${FLAMERIG_BUILD_DIR:-build}/tools/flamerig"
case "$BIN" in /*) ;; *) BIN="$PWD/$BIN" ;; esac
START=$(date +%s)

# 1. The synthetic fire and board.
"$BIN" simulate --config config/sim_rig.yaml --out "$RUN_DIR"
FRAMES=$(find "$RUN_DIR/truth" -name "frame_*.vdb" | wc -l)

# 2. Calibration: the sim cameras replay the board views (a board waved in front of the rig; a
# camera that does not see it shows a dark frame) at 10 Hz into a recording of one frame set per
# view (camera frame k shows view k mod VIEWS, so any VIEWS consecutive sets hold each view once),
# which `calibrate` turns into a rig (the ring frame put at the candle's base,
# config/calibrate_sim.yaml). A count of sets, not a duration: the same views whenever the daemon
# starts, so the same calibration on every run.
VIEWS=$(find "$RUN_DIR/calibration" -mindepth 1 -maxdepth 1 -type d | wc -l)
cat > "$RUN_DIR/capture_calibration.yaml" <<YAML
data_dir: recordings
sync: hardware-trigger
trigger_rate_hz: 10
pretrigger_seconds: 0
cameras:
  - {name: cam0, width: 320, height: 240, pixel_format: Mono8, sim: {replay: ., replay_content: calibration}}
  - {name: cam1, width: 320, height: 240, pixel_format: Mono8, sim: {replay: ., replay_content: calibration}}
YAML
rm -rf "$RUN_DIR/recordings/calibration"
(cd "$RUN_DIR" && "$BIN" capture --config capture_calibration.yaml --record calibration \
  --frames "$VIEWS" --duration "$(( VIEWS / 10 + 30 ))")
"$BIN" calibrate --recording "$RUN_DIR/recordings/calibration" \
  --board "$RUN_DIR/calibration/board.yaml" --config config/calibrate_sim.yaml \
  --out "$RUN_DIR/calibrated"
# 2b. Radiometry: simulate filmed a black-body calibrator with each camera (radiometry/shots.yaml:
# three temperatures, six exposure times each, given as the camera took them, in microseconds at
# 0 dB, with the exposure time that exposure 1 stands for). The calibrated rig gets each camera's
# gains and black level, and keeps that unit, so that `run` knows a recording's exposure from its
# cameras' settings.
"$BIN" calibrate-radiometry --rig "$RUN_DIR/calibrated/rig.yaml" \
  --shots "$RUN_DIR/radiometry/shots.yaml" --out "$RUN_DIR/calibrated_radiometry"
RIG="$RUN_DIR/calibrated_radiometry/rig.yaml"

# 3. The fire: two sim cameras on a hardware trigger line replay the dataset's frames for one pass
# through them and one set more (frame k of a camera shows dataset frame k mod FRAMES) into a
# lossless recording, which is also exported as PNG frame sets. They are colour machine-vision
# cameras sending their sensor's Bayer mosaic (BayerRG8, the camera's sRGB gamma on): each pixel
# records one colour, and the other two are interpolated on the host (OpenCV's demosaicing) before
# the tomography and the fit, with the colour fringes that leaves at the flame's edges.
cat > "$RUN_DIR/capture.yaml" <<YAML
data_dir: recordings
sync: hardware-trigger
trigger_rate_hz: 10
pretrigger_seconds: 0
cameras:
  - {name: cam0, width: 320, height: 240, pixel_format: BayerRG8, exposure_us: 10000, gain_db: 0, sim: {replay: .}}
  - {name: cam1, width: 320, height: 240, pixel_format: BayerRG8, exposure_us: 10000, gain_db: 0, sim: {replay: .}}
YAML
rm -rf "$RUN_DIR/recordings/fire"
(cd "$RUN_DIR" && "$BIN" capture --config capture.yaml --record fire \
  --frames "$(( FRAMES + 1 ))" --duration "$(( FRAMES / 10 + 30 ))")
rm -rf "$RUN_DIR/recorded"
"$BIN" export --recording "$RUN_DIR/recordings/fire" --out "$RUN_DIR/recorded"

# 4. Every recorded frame set: tomography and fit through the calibrated rig. The exposure is
# known, not fitted: the first camera's settings at the recording's start (10000 us at 0 dB,
# recorded with the take) over the exposure unit of the radiometric calibration; printed below
# beside the simulator's (dataset.yaml), which the run does not read. The truth of a set
# is the dataset frame its cameras showed (frame id mod FRAMES). The truth is in the simulator's
# rig frame, the calibration chose its own (a few millimetres and milliradians away: 2.7 mm and
# 5.6 mrad with these 72 views): --truth-rig moves the truth into the calibrated frame before it is
# scored.
rm -rf "$RUN_DIR/run"
"$BIN" run --recording "$RUN_DIR/recordings/fire" --rig "$RIG" \
  --truth "$RUN_DIR/truth" --truth-rig "$RUN_DIR/rig.yaml" --out "$RUN_DIR/run"

# 4b. The same frames fitted with one temperature and density per ring about the flame's axis
# (README, `run --axisymmetric`): a candle is nearly axisymmetric, and from two views the rings hold
# its temperatures far better than free voxels do. Both runs scored side by side, with a constant
# temperature (the truth's own spread) as the baseline either must beat.
rm -rf "$RUN_DIR/run_axisymmetric"
"$BIN" run --recording "$RUN_DIR/recordings/fire" --rig "$RIG" \
  --truth "$RUN_DIR/truth" --truth-rig "$RUN_DIR/rig.yaml" --axisymmetric \
  --no-blender --out "$RUN_DIR/run_axisymmetric"
score() {  # frames.csv, grid|rings -> the frame sets' temperature error, bias, sigma coverage
  python3 - "$1" "$2" <<'PY'
import csv, sys
# A frame not scored against the truth says -1 (pipeline/run.h), as does a sigma not estimated.
rows = [r for r in csv.DictReader(open(sys.argv[1])) if float(r.get("truth_rms_k") or -1) >= 0]
def span(key, scale=1.0, signed=False):  # a bias may be negative; the others say -1 for none
    v = [scale * float(r[key]) for r in rows
         if r.get(key) and float(r[key]) == float(r[key]) and (signed or float(r[key]) >= 0)]
    return (min(v), max(v)) if v else (float("nan"), float("nan"))
if not rows:
    print("no frame set scored against the truth")
else:
    weighted = span("truth_weighted_bias_k", signed=True)  # none from a build before 2026-12-03
    print("%d frame sets: T RMS %.0f..%.0f K, bias %+.0f..%+.0f K%s, %.0f..%.0f%% of the visible "
          "voxels within one sigma (a constant temperature: %.0f..%.0f K)"
          % ((len(rows),) + span("truth_rms_k") + span("truth_bias_k", signed=True)
             + ((" (weighted by the truth's emission %+.0f..%+.0f K)" % weighted
                 if weighted[0] == weighted[0] else ""),)
             + span("truth_within_1_sigma", 100) + span("truth_spread_k")))
    total = [float(r["soot"]) / float(r["truth_soot"]) for r in rows
             if float(r.get("truth_soot") or 0) > 0]
    seen = [(float(r["visible_soot"]) / float(r["truth_visible_soot"]),
             float(r["truth_visible_soot"]) / float(r["truth_soot"])) for r in rows
            if float(r.get("truth_visible_soot") or 0) > 0]  # none before 2026-12-05
    if total:
        print("    soot: %.2f..%.2f of the truth's%s" % (min(total), max(total), (
            "; in the truth's visible voxels %.2f..%.2f of the truth's there (which holds "
            "%.2f..%.2f of its soot)" % (min(s[0] for s in seen), max(s[0] for s in seen),
                                         min(s[1] for s in seen), max(s[1] for s in seen))
            if seen else "")))
    # The fit's limit: the truth as its grid (or its rings) could at best show it, scored alike.
    limit = [r for r in rows if float(r.get("limit_rms_k") or -1) >= 0
             and float(r.get("truth_visible_soot") or 0) > 0]  # none before 2026-12-05
    if limit:
        ratio = [float(r["limit_visible_soot"]) / float(r["truth_visible_soot"]) for r in limit]
        over = [float(r["limit_soot"]) / float(r["truth_soot"]) for r in limit]
        rms = [float(r["limit_rms_k"]) for r in limit]
        bias = [float(r["limit_bias_k"]) for r in limit]
        print("    its limit (the truth as its %s could show it; %d sets): T RMS %.0f..%.0f K, "
              "bias %+.0f..%+.0f K, soot %.2f..%.2f of the truth's, in the visible voxels "
              "%.2f..%.2f" % (sys.argv[2], len(limit), min(rms), max(rms), min(bias), max(bias),
                              min(over), max(over), min(ratio), max(ratio)))
    for bound in ("temperature", "density"):  # held there by the fit's bound, not by the images
        pinned = [(r["frame"], int(r["voxels_at_%s_bound" % bound])) for r in rows
                  if int(r.get("voxels_at_%s_bound" % bound) or 0) > 0]
        print("    voxels at the %s bound: %s" % (bound, ", ".join(
            "%d on set %s" % (n, f) for f, n in pinned) if pinned else "none"))
PY
}
echo
python3 - "$RUN_DIR/run/frames.csv" "$RUN_DIR/dataset.yaml" <<'PY'
import csv, re, sys
held = sorted({r["exposure"] for r in csv.DictReader(open(sys.argv[1])) if r["exposure"]})
truth = re.search(r"^  exposure: (\S+)", open(sys.argv[2]).read(), re.M).group(1)
print("exposure held by run (from the recorded camera settings and the radiometric calibration's "
      "unit): %s; the simulator's: %.6g" % (", ".join("%.6g" % float(v) for v in held), float(truth)))
PY
echo "temperatures against the truth (visible voxels, truth moved into the calibrated frame):"
echo "  free voxels (run):            $(score "$RUN_DIR/run/frames.csv" grid)"
echo "  rings (run --axisymmetric):   $(score "$RUN_DIR/run_axisymmetric/frames.csv" rings)"

# 5. The first fitted frame lighting a small still life, beside the usual point and sphere lights.
FIRST=$(find "$RUN_DIR/run" -maxdepth 1 -name "frame_*.vdb" | sort | head -1)
"$BIN" render --scene config/scene_candle.yaml --volume "$FIRST" --samples 32 --out "$RUN_DIR/scene"

echo
echo "main job done in $(( $(date +%s) - START )) s after the build. Open:"
echo "  $RUN_DIR/run/report/index.html   the report: error against the truth, input against"
echo "                                   rendered views, temperature slices, run time per frame"
echo "  $RUN_DIR/run/frame_NNNNNN.vdb    fitted temperature (K) and density (m^-3) per frame"
echo "  $RUN_DIR/run/blender/            the same as a Blender-ready .vdb sequence (README)"
echo "  $RUN_DIR/run_axisymmetric/report/index.html   the same frames fitted as rings about the"
echo "                                   flame's axis, with radial profiles (T(r, h) and its sigma)"
echo "  $RUN_DIR/scene/compare.png       the fitted fire lighting a scene, against a point and a"
echo "                                   sphere light (fire.exr: the linear HDR render)"
echo "  $RUN_DIR/calibrated/report.md    the rig calibrated from the recorded board views"
echo "  $RUN_DIR/calibrated_radiometry/report.md   the cameras' gains from the black body"
echo "  $RUN_DIR/recordings/             the capture daemon's recordings (calibration, fire),"
echo "                                   exported to $RUN_DIR/recorded"
echo "  $RUN_DIR/preview.png             the simulated dataset"
