// The forward model: an emission-absorption ray marcher that renders what a calibrated camera sees
// of a temperature and soot-density volume.
//
// Physics (DESIGN section 5): along each camera ray,
//     L(lambda) = integral kappa(x, lambda) B(lambda, T(x)) exp(-tau(x, lambda)) ds,
// with kappa = density * cross_section(lambda) (absorption.h), B Planck's law, tau the optical
// depth from the camera to x, and no scattering. Emission is absorption times Planck (Kirchhoff):
// kappa appears once.
//
// Discretisation: each voxel's absorption kappa_j = sigma * n_j and emission kappa_j * B(T_j) are
// computed once (SetVolume) and sampled trilinearly (voxel centres at integer index coordinates,
// values clamped at the grid's border; tomography/ray_march.h) at the midpoint of each step of
// length step_voxels * (smallest voxel edge) along the ray, the last step shortened to end exactly
// at the box. Within a step the medium is taken as constant, and the step's contribution is
// integrated exactly: L += Tr * (1 - exp(-kappa ds)) * emission / kappa, Tr *= exp(-kappa ds). A
// homogeneous medium is therefore rendered exactly at any step size; smooth media converge as the
// step shrinks. Interpolating emission rather than temperature makes the optically thin limit
// exactly linear in the per-voxel emission: it is the tomography's model
// (tomography/system_matrix.h), term for term.
//
// Paths, chosen automatically (RenderOptions::path = kAuto) and reported in the summary:
//  - fast (grey absorption): the spectrum collapses into a per-kelvin XYZ table; each ray carries
//    3 channels and one transmittance.
//  - spectral (wavelength-dependent absorption, e.g. soot): each ray carries one radiance and one
//    transmittance per wavelength bin; XYZ from the bins' colour matching weights. Each voxel
//    points into a per-kelvin table of the bins' Planck radiance (16 bytes a voxel, the table
//    shared and in cache), the bins are processed eight at a time as vectors, and a step whose
//    optical depth is below 1e-2 in every bin takes 1 - exp(-tau) from its series without an
//    exponential (the value the exact form gives there too).
// Skipped work, also reported: empty space (bricks of brick_size^3 voxels whose density, dilated by
// one voxel for the trilinear stencil, is zero; skipping is exact) and rays whose transmittance
// fell below min_transmittance (early termination; the error is at most that fraction of what lies
// behind).
//
// Output: a 3-channel float image of linear sRGB radiance (W m^-2 sr^-1 nm^-1,
// luminance-normalised, see colour.h) before exposure, or with RenderOptions::response the
// camera's own channels in the same units (camera_response.h). ApplyCameraResponse() turns it into
// what an 8-bit sRGB camera records; RecordCameraImage() (pipeline) what any camera records.
//
// Gradients (RenderGradient): the adjoint of Render(). Given dLoss/d(linear RGB) for every pixel,
// one backward pass per ray (the ray is marched forward once to get its radiance, then again with
// the adjoint recurrences) accumulates dLoss/dT and dLoss/dn for every voxel. Exact derivatives of
// the discretised model above (the same steps, skipped bricks and early termination); the
// temperature derivative is that of the tables the renderer interpolates (piecewise linear in T at
// 1 K spacing). Per-step quantities (tau = kappa ds, Tr the transmittance before the step, R_after
// the radiance contributed behind it, g the adjoint of the ray's radiance):
//     dLoss/dE_step   = g Tr ds phi(tau),                 phi(tau) = (1 - exp(-tau)) / tau
//     dLoss/dkappa_step = g Tr ds tau phi'(tau) S - g ds R_after,   S = E / kappa
// spread to the voxels with the trilinear weights, then through E_j = sigma n_j B(T_j) and
// kappa_j = sigma n_j (on the spectral path the per-bin emission adjoint is accumulated per voxel
// and contracted with B(T) and B'(T) once at the end). Each thread accumulates into private
// buffers (atomics were 7 to 14 times slower, DESIGN section 8). Only voxels with density > 0
// receive gradients: the others are outside the medium (and their bricks may be skipped).
//
// Speed: the float kernels have a second build for AVX2 with FMA, chosen at run time when the CPU
// has both (core/cpu.h; RenderOptions::wide_kernels = false keeps the baseline), and a ray looks
// up each brick it crosses once. `flamerig benchmark render` measures both builds side by side.
//
// Thread safety: Render() is const and may be called concurrently on one FireRenderer; it runs its
// own TBB parallel loop over image rows. SetVolume() must not run concurrently with Render().
#ifndef FLAMERIG_FITTING_RENDERER_H_
#define FLAMERIG_FITTING_RENDERER_H_

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "calibration/camera_rays.h"
#include "core/image.h"
#include "core/memory.h"
#include "fitting/absorption.h"
#include "fitting/camera_response.h"
#include "fitting/spectral_tables.h"
#include "tomography/ray_march.h"
#include "tomography/volume.h"

namespace flamerig {

enum class SpectralPath { kAuto, kFast, kSpectral };
const char* ToString(SpectralPath path);

struct RenderOptions {
  // March step in units of the smallest voxel edge; (0, 4].
  double step_voxels = 0.5;
  // A ray stops once its transmittance (every bin's, on the spectral path) is below this; [0, 1).
  double min_transmittance = 1e-4;
  // Skip bricks with no density (exact).
  bool skip_empty_space = true;
  // Edge of the empty-space bricks, voxels; [2, 64].
  int brick_size_voxels = 8;
  // kAuto: fast for grey absorption, spectral otherwise. kFast with non-grey absorption is an
  // error.
  SpectralPath path = SpectralPath::kAuto;
  // Wavelength bins of the spectral path: centres first..last nm in steps of step nm, for the sRGB
  // observer. A camera's own response (below) puts them where it responds instead
  // (ChannelResponse::support_first_nm .. support_last_nm, within 300..1100 nm), centred on that
  // range in steps of step nm: a mono camera behind an 850 nm filter is rendered at 850 nm (with
  // first..last it was black), and one behind a 650/40 nm filter in 17 bins rather than 41; a
  // bare sensor from 300 to 1100 nm takes 81.
  double spectral_first_nm = 380.0;
  double spectral_last_nm = 780.0;
  double spectral_step_nm = 10.0;
  // March in double instead of float precision (slower; for reference renders and tests).
  bool double_precision = false;
  // The float kernels' AVX2 + FMA build when the CPU has it (core/cpu.h); false: the baseline
  // (SSE2) build, for benchmarks and tests that compare the two. Same results up to rounding.
  bool wide_kernels = true;
  // The camera's spectral response (camera_response.h): what the output channels are. Null: the
  // sRGB observer, linear sRGB out. The spectral path sees its bins' range (the observer's 360..830
  // nm at most; a camera's, where it responds); the fast path integrates the response's whole range.
  std::shared_ptr<const ChannelResponse> response;

  // Throws InputError naming the field, its value and the rule.
  void Validate() const;
};

struct RenderSummary {
  SpectralPath path_used = SpectralPath::kFast;
  std::string path_reason;  // why that path
  int spectral_bins = 3;    // channels carried per ray
  std::int64_t rays = 0;    // pixels rendered
  std::int64_t rays_hit_box = 0;
  std::int64_t rays_terminated_early = 0;    // stopped by min_transmittance
  std::int64_t steps_evaluated = 0;          // samples of the medium taken
  std::int64_t steps_skipped_empty = 0;      // steps jumped over in empty bricks
  std::int64_t steps_after_termination = 0;  // steps not taken after early termination
  double occupied_brick_fraction = 1.0;
  bool wide_kernels = false;  // the AVX2 + FMA build ran (RenderOptions::wide_kernels)
  double time_ms = 0.0;

  std::string BriefReport() const;
};

class FireRenderer {
 public:
  // Throws InputError for invalid options, or kFast requested with non-grey absorption.
  FireRenderer(const AbsorptionModel& absorption, const RenderOptions& options = RenderOptions());

  // Copies the volume in (float). Validates: sizes match the geometry, every value finite and >= 0
  // (InputError naming the field and voxel). Builds the empty-space bricks.
  void SetVolume(const GridGeometry& geometry, const std::vector<float>& temperature_k,
                 const std::vector<float>& density_per_m3);

  // Renders the linear sRGB radiance seen through `rays` into `linear_rgb` (resized to the camera,
  // 3 channels). Requires SetVolume() first.
  RenderSummary Render(const CameraRays& rays, ImageF* linear_rgb) const;

  // The same over each pixel's area, as a sensor integrates light: the mean radiance of n x n rays
  // through a regular grid of points inside every pixel of `camera` (offsets (s + 0.5) / n - 0.5;
  // n = 1 is Render through the centres). The rays are unprojected here, one set at a time, so
  // memory does not grow by n^2. Returns the summary of the last set rendered. n in [1, 8].
  RenderSummary RenderPixelArea(const CameraModel& camera, int n, ImageF* linear_rgb) const;

  // The same for rays that end at an opaque surface: max_distance_m (one per pixel, metres along the
  // ray from its origin; +inf = no surface) ends the march there; when not null,
  // *transmittance_rgb (3 channels) receives the fraction of the surface's light that crosses the
  // medium to the camera: the grey transmittance on the fast path; on the spectral path the bins'
  // transmittances averaged with xbar, ybar, zbar for R, G, B (exact for grey surfaces seen through
  // grey media, an approximation otherwise). Throws InputError when max_distance_m does
  // not have one value per pixel.
  RenderSummary Render(const CameraRays& rays, const std::vector<float>& max_distance_m,
                       ImageF* linear_rgb, ImageF* transmittance_rgb) const;

  // Adds dLoss/dT (per kelvin) and dLoss/dn (per particle/m^3) of every voxel to the two arrays
  // (resized to the grid and zeroed when empty; otherwise they must have one value per voxel),
  // given d_loss_d_rgb: dLoss/d(linear sRGB radiance) per pixel, 3 channels, the camera's size.
  // Pixels whose three derivatives are zero are not marched. Requires SetVolume() first.
  RenderSummary RenderGradient(const CameraRays& rays, const ImageF& d_loss_d_rgb,
                               std::vector<double>* d_temperature,
                               std::vector<double>* d_density) const;

  // dLoss/d(linear RGB) of pixel (x, y) given what the renderer made of it (RenderAndGradient).
  using PixelGradient = std::function<Eigen::Vector3d(int x, int y, const Eigen::Vector3d& rgb)>;

  // Render() and RenderGradient() in one pass over the rays: each ray is marched for its radiance
  // (written into `linear_rgb` as Render() writes it), `pixel_gradient` then gives dLoss/dRGB for
  // that pixel, and a non-zero one is marched back through the adjoint into the two arrays as
  // RenderGradient() does (two marches a ray instead of Render's one and RenderGradient's two).
  // `pixel_gradient` is called exactly once for every pixel (with zero radiance for rays that
  // miss the box), from several threads at once for different pixels. Requires SetVolume().
  RenderSummary RenderAndGradient(const CameraRays& rays, const PixelGradient& pixel_gradient,
                                  ImageF* linear_rgb, std::vector<double>* d_temperature,
                                  std::vector<double>* d_density) const;

  // The Gauss-Newton curvature of a least-squares data term, per voxel and exact (no random
  // probes). `pixel_jacobians` holds, for every pixel (index y * width + x), the 3x3 Jacobian J_p
  // of its three residuals with respect to its linear RGB as rendered from this volume (row k:
  // dr_k/dRGB); a pixel whose J_p is all zero does not count and is not marched. Adds to every
  // voxel with medium its diagonal block of J^T J over (T in kelvin, n per m^3):
  //   tt += sum_p sum_k (dr_pk/dT)^2,  tn += sum_p sum_k (dr_pk/dT)(dr_pk/dn),
  //   nn += sum_p sum_k (dr_pk/dn)^2.
  // Arrays as RenderGradient's (resized to the grid and zeroed when empty). How: the adjoint's
  // per-step factors (see above) do not depend on which residual is differentiated, and each
  // ray's three residuals have constant adjoints along it; so a ray is marched as for
  // RenderGradient, keeping for each voxel it crosses two per-bin sums (emission and absorption
  // parts), and when the ray ends they are contracted with the voxel's spectrum and the three
  // residuals' adjoints into the voxel's 3x2 Jacobian, whose outer product is added. About the
  // cost of one gradient pass, where a Hutchinson estimate needs one per probe.
  RenderSummary RenderCurvature(const CameraRays& rays,
                                const std::vector<Eigen::Matrix3f>& pixel_jacobians,
                                std::vector<double>* tt, std::vector<double>* tn,
                                std::vector<double>* nn) const;

  // One marched ray's Jacobian, voxel by voxel (RenderJacobian): the pixel (index y * width + x),
  // the voxels with medium its ray crosses (flat grid indices, each once, in the order first
  // crossed), and for each the 3 x 2 Jacobian of the pixel's three residuals with respect to the
  // voxel's temperature (column 0, per kelvin) and density (column 1, per particle/m^3).
  struct RayJacobian {
    std::size_t pixel = 0;
    std::vector<std::uint32_t> voxels;
    std::vector<Eigen::Matrix<double, 3, 2>> d;
  };
  using RayJacobianVisitor = std::function<void(const RayJacobian&)>;
  // What RenderCurvature sums, ray by ray: the same pass, with the same `pixel_jacobians` and the
  // same exact per-voxel Jacobians, handed to `visit` instead of being summed into each voxel's
  // diagonal block, so that a caller can build J^T J over parameters that several voxels share
  // (a tied fit's rings, fitting/fit.cc's Levenberg-Marquardt) or couple voxels along a ray.
  // `visit` is called once for every marched ray that crosses medium, from several threads at
  // once; the reference is valid during the call only. Throws InputError as RenderCurvature.
  RenderSummary RenderJacobian(const CameraRays& rays,
                               const std::vector<Eigen::Matrix3f>& pixel_jacobians,
                               const RayJacobianVisitor& visit) const;

  const AbsorptionModel& absorption() const { return absorption_; }
  const RenderOptions& options() const { return options_; }
  SpectralPath path() const { return path_; }

 private:
  template <typename Real>
  RenderSummary RenderImpl(const CameraRays& rays, ImageF* linear_rgb,
                           const std::vector<float>* max_distance_m = nullptr,
                           ImageF* transmittance_rgb = nullptr) const;
  // d_loss_d_rgb, or pixel_gradient and linear_rgb (RenderAndGradient).
  template <typename Real>
  RenderSummary GradientImpl(const CameraRays& rays, const ImageF* d_loss_d_rgb,
                             const PixelGradient* pixel_gradient, ImageF* linear_rgb,
                             std::vector<double>* d_temperature,
                             std::vector<double>* d_density) const;
  // Into the blocks tt, tn, nn (RenderCurvature), or to `visit` when it is not null
  // (RenderJacobian; the blocks are then not touched).
  template <typename Real>
  RenderSummary CurvatureImpl(const CameraRays& rays,
                              const std::vector<Eigen::Matrix3f>& pixel_jacobians,
                              std::vector<double>* tt, std::vector<double>* tn,
                              std::vector<double>* nn, const RayJacobianVisitor* visit) const;
  // Resizes and zeroes (when empty) or checks the gradient arrays.
  void PrepareGradientArrays(std::vector<double>* d_temperature,
                             std::vector<double>* d_density) const;
  // Marches one ray over the occupied bricks: visit(ds, corner[8], weight[8]) for every step
  // evaluated, until it returns false (early termination). Counts into the counters.
  struct MarchCounters;
  // The summary of a render or gradient pass that started at `start`.
  RenderSummary Summarise(std::chrono::steady_clock::time_point start, std::int64_t rays, int bins,
                          const MarchCounters& totals) const;
  template <typename Real, typename Visit>
  void MarchRay(const RayMarch& march, MarchCounters* counters, Visit&& visit) const;
  // The per-row kernels behind RenderImpl and GradientImpl; the *Wide ones are the same float
  // kernels compiled for AVX2 and FMA, used when the CPU has them (UseWideKernels, renderer.cc).
  struct RenderJob;
  struct GradientJob;
  template <typename Real>
  struct GradientBuffers;
  template <typename Real>
  Real GatherCorners(const std::size_t* corner, const Real* weight, std::int32_t* slot,
                     const float** rows, Real* u0, Real* u1) const;
  // The fast path's sample: absorption kappa = sum w kappa_corner and source S = emission /
  // kappa per XYZ channel; false where kappa is 0 (RenderImpl's model).
  template <typename Real>
  bool FastSample(const std::size_t* corner, const Real* weight, Real* kappa, Real* source) const;
  // The first pass of an adjoint (GradientRows, CurvatureRows): marches the ray for its radiance
  // into `total` and its transmittance (per bin on the spectral path, else XYZ and one
  // transmittance), both set by the caller; `sigma` per padded bin, `sigma_max` their largest,
  // `clearest` the bin of the smallest (renderer.cc's BinCrossSections).
  template <typename Real>
  void MarchRadiance(const RayMarch& march, bool spectral, int nbp, const Real* sigma,
                     Real sigma_max, int clearest, Real min_transmittance, Real* total,
                     Real* transmittance) const;
  template <typename Real>
  void RenderRows(const RenderJob& job, int y0, int y1, MarchCounters* counters) const;
  void RenderRowsWide(const RenderJob& job, int y0, int y1, MarchCounters* counters) const;
  template <typename Real>
  void GradientRows(const GradientJob& job, int y0, int y1, GradientBuffers<Real>* buffers,
                    MarchCounters* counters) const;
  void GradientRowsWide(const GradientJob& job, int y0, int y1, GradientBuffers<float>* buffers,
                        MarchCounters* counters) const;
  template <typename Real>
  struct CurvatureBuffers;
  template <typename Real>
  void CurvatureRows(const GradientJob& job, const std::vector<Eigen::Matrix3f>& jacobians, int y0,
                     int y1, const RayJacobianVisitor* visit, CurvatureBuffers<Real>* buffers,
                     MarchCounters* counters) const;
  void CurvatureRowsWide(const GradientJob& job, const std::vector<Eigen::Matrix3f>& jacobians,
                         int y0, int y1, const RayJacobianVisitor* visit,
                         CurvatureBuffers<float>* buffers, MarchCounters* counters) const;

  AbsorptionModel absorption_;
  RenderOptions options_;
  SpectralPath path_;
  std::string path_reason_;
  std::shared_ptr<const ChannelResponse> response_;  // never null
  std::unique_ptr<SpectralBins> bins_;
  std::vector<double> bin_cross_section_m2_;

  GridGeometry geometry_;
  // Fast path: per voxel {kappa, X, Y, Z}: absorption (1/m) and the XYZ of B(T).
  // The voxel arrays that rays read at random are backed by huge pages (core/memory.h).
  std::vector<float, HugePageAllocator<float>> fast_;
  // Per voxel: temperature (for the gradient's table derivatives).
  std::vector<float> temperature_;
  // Per voxel density; per voxel with density > 0 a slot (-1 elsewhere) and the slot's voxel.
  std::vector<float> density_;
  std::vector<std::int32_t, HugePageAllocator<std::int32_t>> slot_;
  std::vector<std::uint32_t> active_voxels_;
  // Spectral path: the Planck radiance of every bin per kelvin over the volume's temperatures
  // (SpectralBins' 1 K table, copied so that it stays in cache; rows padded to a multiple of
  // kLanes bins, the first two all zero), and per voxel, in one 16-byte record as the fast path's
  // fast_, its density, its slot and where its spectrum lies in the table: B_b(T) = row[b] +
  // fraction * (next_row[b] - row[b]), the difference being dB_b/dT per kelvin. Each distinct
  // temperature beyond the table gets two rows, B(T) and dB/dT itself (exact), with fraction 0;
  // a voxel without medium points at the zero rows.
  static constexpr int kLanes = 8;
  struct SpectralVoxel {
    float density = 0;  // the voxel's over density_unit_: at most 1
    std::int32_t slot = -1;
    std::uint32_t offset = 0;  // into spectral_table_
    float fraction = 0;
  };
  // The largest density of the volume (1 for none). A density below about 1e-38 of it (float's
  // range) counts as none on the spectral path: its light and absorption are as far below the
  // densest voxel's.
  float density_unit_ = 1;
  int padded_bins_ = 0;              // the bin count rounded up to kLanes
  std::size_t hot_rows_offset_ = 0;  // where the rows of temperatures beyond the table begin
  std::vector<float, HugePageAllocator<float>> spectral_table_;  // rows aligned to 32 bytes
  std::vector<SpectralVoxel, HugePageAllocator<SpectralVoxel>> spectral_voxels_;  // per voxel
  Eigen::Vector3i brick_dims_ = Eigen::Vector3i::Zero();
  std::vector<std::uint8_t> brick_occupied_;
  double occupied_brick_fraction_ = 0;
  bool has_volume_ = false;
};

// What an 8-bit camera records: clamp(exposure * linear_rgb, 0, 1), sRGB-encoded, rounded to 8
// bits. Throws InputError unless exposure is finite and > 0 and the image has 3
// channels.
ImageU8 ApplyCameraResponse(const ImageF& linear_rgb, double exposure);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_RENDERER_H_
