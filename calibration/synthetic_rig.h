// Synthetic rigs and calibration boards whose truth is known (STYLE.md 10), used by `flamerig
// simulate`, the benchmarks and the tests: a ring of cameras around a reconstruction box, and
// calibration boards (ChArUco or chessboard) ray-traced through each camera's lens model with
// anti-aliasing and sensor noise. Deterministic: the same options and seeds give bit-identical
// output.
#ifndef FLAMERIG_CALIBRATION_SYNTHETIC_RIG_H_
#define FLAMERIG_CALIBRATION_SYNTHETIC_RIG_H_

#include <cstdint>
#include <string>
#include <vector>

#include "calibration/board.h"
#include "calibration/rig.h"
#include "core/image.h"
#include "core/progress.h"

namespace flamerig::synthetic {

struct RingOptions {
  int cameras = 2;  // [1, 16]
  std::vector<double>
      azimuths_deg;            // one per camera; empty: 0 and 90 for two cameras, else 360/N apart
  double distance_m = 0.3;     // from the box centre to each camera
  double elevation_deg = 0.0;  // above the box centre's horizontal plane
  int width = 320;
  int height = 240;
  double fill = 0.85;  // fraction of the image height the box's bounding sphere spans
  // Any mrcal lens model with an fx fy cx cy core ("LENSMODEL_OPENCV8", "LENSMODEL_PINHOLE",
  // "LENSMODEL_SPLINED_STEREOGRAPHIC_...", ...).
  std::string lensmodel = "LENSMODEL_OPENCV8";
  // The model's parameters after the core, the same for every camera. Empty: OPENCV8 cameras get
  // a mild barrel distortion (k1 about -0.06, slightly different per camera), other models zeros.
  // A strong lens: LENSMODEL_OPENCV8 with {-0.3, 0.08, 0, 0, 0, 0, 0, 0}.
  std::vector<double> distortion;
  void Validate() const;
};

// A ring of cameras around the box, all looking at its centre, y up. Camera i sits at azimuth a_i:
// position = centre + distance * (sin a cos e, sin e, cos a cos e).
Rig MakeRingRig(const Box3& box, const RingOptions& options, const std::string& name = "sim");

// A row of cameras side by side, `spacing_m` apart along rig x and centred on the box, at
// `options.distance_m` from the box centre along +z and all looking along -z: parallel optical
// axes, a stereo pair for two cameras. Azimuths and elevation are not used.
Rig MakeRowRig(const Box3& box, const RingOptions& options, double spacing_m,
               const std::string& name = "sim");

// Boards are described in calibration/board.h.
using flamerig::BoardSpec;
using flamerig::BoardType;

// How the board is lit and seen, beyond the lens: what real photographs of a board have.
struct BoardLighting {
  // A shadow across the board: the light left in it (1: no shadow). Its edge is a line through the
  // pattern's centre turned by `shadow_angle_deg` from board y and moved by `shadow_offset_m` along
  // its normal (n = (cos a, sin a) in board x, y); the side n . (p - centre) > offset is in shadow,
  // with a soft edge `penumbra_m` wide.
  double shadow = 1.0;
  double shadow_angle_deg = 0;
  double shadow_offset_m = 0;
  double penumbra_m = 0.002;
  // The light falls linearly along board x by this fraction from one end of the pattern to the
  // other (a lamp to one side).
  double gradient = 0;
  // Gaussian blur (defocus, motion), sigma in pixels, before the noise.
  double blur_px = 0;
  // Throws InputError naming the field.
  void Validate() const;
};

// Renders the board seen by `camera` (8-bit grey), anti-aliased with `supersample`^2 rays per
// pixel, on a dark background, plus Gaussian noise of `noise_dn` (8-bit units) drawn from `seed`.
// Any mrcal lens model projects: the rays come from the camera model's own unprojection.
ImageU8 RenderBoard(const CameraModel& camera, const BoardSpec& board, const Rigid3& rig_from_board,
                    double noise_dn, std::uint64_t seed, int supersample = 3,
                    const BoardLighting& lighting = {});
// The same with the camera's pixel rays already unprojected (camera.UnprojectAllPixels()), which
// saves the unprojection when rendering many views.
ImageU8 RenderBoard(const CameraModel& camera, const std::vector<Ray>& pixel_rays,
                    const BoardSpec& board, const Rigid3& rig_from_board, double noise_dn,
                    std::uint64_t seed, int supersample = 3, const BoardLighting& lighting = {});

struct BoardView {
  Rigid3 rig_from_board;
  std::vector<int> cameras;  // cameras that see the whole printed side of the board
  std::string kind;          // "shared" (between neighbours) or "closeup"
};

// Board poses for calibrating a ring: for each pair of neighbouring cameras, `shared_per_pair`
// poses near the box centre turned towards both; for each camera `closeups_per_camera` poses close
// to it. Only cameras that see every corner of the board (inside the image, with a margin) are
// listed.
std::vector<BoardView> MakeCalibrationViews(const Rig& rig, const BoardSpec& board,
                                            std::uint64_t seed, int shared_per_pair,
                                            int closeups_per_camera);

struct WrittenViews {
  int views = 0;   // board poses
  int images = 0;  // images written (a view's cameras that see the whole board)
  // The images of view 0 per camera, for a preview (empty for the cameras that do not see it).
  std::vector<ImageU8> first_view;
};

// Renders calibration views of `board` for `rig` (MakeCalibrationViews with seed + 1; noise of
// max(noise_dn, 1) DN when noise_dn > 0, seeded per view and camera from `seed`) and writes them as
// `dir`/view_NNN/<camera>.png (8-bit grey), with `dir`/board.yaml: the board and every view's true
// pose (rt_rig_from_board) and cameras. Progress: stage "calibration views", unit "views";
// cancellation throws Cancelled. Throws IoError naming a file that cannot be written. With a
// shadow in `lighting`, each view's shadow edge is turned to its own seeded random angle (a shadow
// across a different half of every board); its offset, penumbra, gradient and blur are as given.
WrittenViews WriteCalibrationViews(const Rig& rig, const BoardSpec& board, std::uint64_t seed,
                                   int shared_per_pair, int closeups_per_camera, double noise_dn,
                                   const std::string& dir,
                                   const ProgressCallback& progress = nullptr,
                                   const BoardLighting& lighting = {});

}  // namespace flamerig::synthetic

#endif  // FLAMERIG_CALIBRATION_SYNTHETIC_RIG_H_
