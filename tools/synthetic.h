// The synthetic fire rig: cameras, fires and calibration boards whose truth is known. Library code
// driven by options with fixed seeds (deterministic: the same options give bit-identical output),
// used by `flamerig simulate`, the benchmarks and the tests.
//
// Fires are procedural fields of temperature (K) and soot number density (m^-3) defined in the
// normalised coordinates of the reconstruction box (x and z across, y up from the box floor), so
// they fill any box. Two kinds:
//  - candle: one teardrop flame, a cooler core and a hot sheath, soot in the upper half, a gentle
//    sway over time; peak about 2000 K (candles measure 1350..2050 K) and soot volume fraction
//    about 1e-6.
//  - licks: several turbulent tongues of flame from a shared base (count, heights, leans and
//    turbulence drawn from the seed), peak about 2100 K.
// Calibration boards (ChArUco or chessboard) are ray-traced through each camera's lens model with
// anti-aliasing and sensor noise.
#ifndef FLAMERIG_TOOLS_SYNTHETIC_H_
#define FLAMERIG_TOOLS_SYNTHETIC_H_

#include <cstdint>
#include <string>
#include <vector>

#include "core/image.h"
#include "calibration/board.h"
#include "calibration/rig.h"
#include "fitting/absorption.h"
#include "tomography/volume.h"

namespace flamerig::synthetic {

enum class FireKind { kCandle, kLicks };
FireKind FireKindFromName(
    const std::string& name);  // "candle" | "licks"; throws std::invalid_argument
const char* ToString(FireKind kind);

struct FireOptions {
  FireKind kind = FireKind::kCandle;
  std::uint64_t seed = 1;
  double time_s = 0.0;                      // animation time; frames of a recording advance it
  double peak_temperature_k = 2000.0;       // hottest temperature of the flame
  double ambient_temperature_k = 300.0;     // temperature outside the flame
  double peak_soot_volume_fraction = 1e-6;  // converted to number density with the absorption model
  int licks = 0;        // licks: number of tongues; 0 = drawn from the seed (3..6)
  int supersample = 2;  // samples per voxel edge when filling the grid; [1, 8]
  // The part of the rig the fire's normalised coordinates span; empty (default): the grid's box.
  Box3 region;
  void Validate() const;
};

// Fills `geometry` with the procedural fire. Returns temperature and density (and no emission).
FireVolume MakeFire(const GridGeometry& geometry, const FireOptions& options,
                    const AbsorptionModel& absorption);

// The emission a renderer sees from each voxel in the optically thin limit, as linear sRGB radiance
// per metre of path: sigma(grey) * density * XYZ(T) -> RGB. For wavelength-dependent absorption the
// spectral integral is done per voxel. This is the ground truth of the tomography.
std::vector<float> ThinEmissionRgb(const FireVolume& fire, const AbsorptionModel& absorption);

struct RingOptions {
  int cameras = 2;  // [1, 16]
  std::vector<double>
      azimuths_deg;            // one per camera; empty: 0 and 90 for two cameras, else 360/N apart
  double distance_m = 0.3;     // from the box centre to each camera
  double elevation_deg = 0.0;  // above the box centre's horizontal plane
  int width = 320;
  int height = 240;
  double fill = 0.85;  // fraction of the image height the box's bounding sphere spans
  std::string lensmodel = "LENSMODEL_OPENCV8";  // or LENSMODEL_PINHOLE
  void Validate() const;
};

// A ring of cameras around the box, all looking at its centre, y up. Camera i sits at azimuth a_i:
// position = centre + distance * (sin a cos e, sin e, cos a cos e). OPENCV8 cameras get a mild,
// realistic distortion.
Rig MakeRingRig(const Box3& box, const RingOptions& options, const std::string& name = "sim");

// Boards are described in calibration/board.h.
using flamerig::BoardSpec;
using flamerig::BoardType;

// Renders the board seen by `camera` (8-bit grey), anti-aliased with `supersample`^2 rays per
// pixel, on a dark background, plus Gaussian noise of `noise_dn` (8-bit units) drawn from `seed`.
ImageU8 RenderBoard(const CameraModel& camera, const BoardSpec& board, const Rigid3& rig_from_board,
                    double noise_dn, std::uint64_t seed, int supersample = 3);
// The same with the camera's pixel rays already unprojected (camera.UnprojectAllPixels()), which
// saves the unprojection when rendering many views.
ImageU8 RenderBoard(const CameraModel& camera, const std::vector<Ray>& pixel_rays,
                    const BoardSpec& board, const Rigid3& rig_from_board, double noise_dn,
                    std::uint64_t seed, int supersample = 3);

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

}  // namespace flamerig::synthetic

#endif  // FLAMERIG_TOOLS_SYNTHETIC_H_
