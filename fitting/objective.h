// The paper's energy (DESIGN section 7), E = w_am * E_am + w_sm * E_sm, and its exact gradient.
//
// The energy is a list of terms, E = sum_k w_k * term_k (EnergyTerm below), that the fast fit
// (through Evaluate, with gradients) and the paper's algorithms (through Evaluate, DataTermAt and
// the local parts of the terms) all evaluate; a new term is a class and one line in MakeTerms
// (objective.cc). The terms now:
//  - Data term E_am: for every pixel of every view, the CIELab distance (CIE76 Delta E) between
//    the rendered pixel and the recorded one. The rendered pixel is what the camera records of the
//    renderer's linear sRGB radiance I: c = clamp(s * I, 0, 1) with s the exposure (no
//    quantisation: the fit sees the continuous value), then c -> XYZ -> Lab (D65 white, colour.h).
//    The recorded pixel is the camera's linear signal (FitView::signal, or the 8-bit sRGB value
//    decoded) taken to Lab the same way. A camera with its own spectral response (FitView::
//    response) is rendered in its own channels, and Lab is then a perceptual metric on them, not
//    a colour: the physics is in the render, the metric only weighs the channels. Clamping at 1 is how saturated
//    input pixels constrain only from below: a render brighter than a saturated channel clamps to
//    it and costs nothing there. A view from a Bayer camera (FitView::mosaic) is compared as the
//    host's demosaicing made it: the render's one measured channel per site, interpolated in the
//    camera's codes as the recording was (fitting/mosaic.h), then taken to Lab.
//  - Pairwise term E_sm: for every active voxel i, the sum over its 18 nearest neighbours j
//    (6 faces, 12 edges) that are also active of |v_j - v_i|, as the paper writes it (each pair
//    counted from both ends), for the temperature and, when density is a per-voxel unknown, the
//    density. Departure from the paper, which does not give v's units: v is the parameter
//    normalised by its search range, (T - T_min) / (T_max - T_min) and (ln n - ln n_min) /
//    (ln n_max - ln n_min). In kelvin, w_sm = 10 would make the pairwise term about a thousand
//    times the data term and flatten every fire. Each pair may weigh apart by its direction
//    (ObjectiveOptions::along_y, across_y; 1 and 1, the paper's, by default): an axisymmetric fit
//    weighs only the pairs along its axis.
//
// Smooth mode (for gradient-based fits): |x| becomes the Charbonnier function
// sqrt(x^2 + eps^2) - eps, for the Delta E of each pixel and for each neighbour difference. The
// exact (non-smooth) terms are always reported alongside, so methods are compared on the paper's
// energy.
//
// Unknowns: temperature and density of the active voxels (every other voxel is empty: density
// 0), and the exposure. The gradient comes from the renderer's adjoint (FireRenderer::
// RenderGradient), one backward pass per view.
#ifndef FLAMERIG_FITTING_OBJECTIVE_H_
#define FLAMERIG_FITTING_OBJECTIVE_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "calibration/camera_rays.h"
#include "core/image.h"
#include "fitting/absorption.h"
#include "fitting/mosaic.h"
#include "fitting/renderer.h"
#include "tomography/volume.h"

namespace flamerig {

struct ObjectiveOptions {
  double w_am = 1.0;   // data term weight (paper: 1); >= 0
  double w_sm = 10.0;  // pairwise term weight (paper: 10); >= 0
  // Charbonnier epsilon: 0 gives the exact (non-smooth) energy. For Delta E in Lab units, and for
  // neighbour differences in normalised units.
  double smooth_delta_e = 0.0;
  double smooth_neighbour = 0.0;
  // Search ranges, which also normalise the pairwise term.
  double t_min_k = 300, t_max_k = 2300;
  double n_min_per_m3 = 0, n_max_per_m3 = 0;  // 0, 0: DensityBounds::Plausible of the model
  // The pairwise term on the per-voxel densities too (Algorithm 1; the fast fit's
  // FitOptions::density_pairwise). Off: the pairwise term is on the temperature only.
  bool density_pairwise = false;
  // The pairwise terms' weight by a pair's direction: a pair whose voxels differ in y only (the
  // grid's vertical axis, an axisymmetric fit's axis: FitOptions::axisymmetric_along_y) weighs
  // w_sm x along_y, every other pair w_sm x across_y. 1 and 1: the paper's term, alike in every
  // direction. Each in [0, kMaxDirectionFactor], and w_sm times either at most kMaxWeight.
  double along_y = 1, across_y = 1;
  static constexpr double kMaxDirectionFactor = 1e3;
  // Views from Bayer cameras (FitView::mosaic) are rendered through their mosaic and the host's
  // demosaicing. Off: their interpolated colours are fitted as if every pixel had measured all
  // three (as until 2026-11-29; for comparison).
  bool model_mosaic = true;
  // The weights w_am and w_sm lie in [0, kMaxWeight]: the stress tests prove the energy and its
  // gradient finite up to there (FitObjective.RejectsBadInput); 1e300 overflowed the energy, and
  // the fit stopped after one step as if converged.
  static constexpr double kMaxWeight = 1e12;
  void Validate() const;  // throws InputError naming the field
};

// One view to match: the camera's rays and its recorded image (3 channels, the camera's size).
struct FitView {
  std::string name;
  const CameraRays* rays = nullptr;
  // What the camera recorded as 8-bit sRGB (for pictures; and the measurement when `signal` is
  // empty: the default camera, calibration/radiometry.h).
  ImageU8 image;
  // The measurement in the camera's linear signal, 3 channels (a mono camera's one channel
  // replicated), 0..1 with 1 saturated: the image decoded through the camera's radiometric model.
  // Empty: SrgbDecode(image / 255).
  ImageF signal;
  // The camera's spectral response (the renderer's output channels); null = the sRGB observer.
  std::shared_ptr<const ChannelResponse> response;
  // A Bayer camera's frames (fitting/mosaic.h): `image` and `signal` are the host's demosaicing of
  // its mosaic, and the data term renders the same of the rendered image. Null: every pixel
  // measured its three channels (RGB and mono frames, plain image files).
  std::shared_ptr<const BayerRecord> mosaic;
};

// One term's part of an evaluation.
struct TermValue {
  std::string name;   // EnergyTerm::name()
  double weight = 0;  // w_k
  double exact = 0;   // the term without smoothing, unweighted
  double smooth = 0;  // the term as minimised (Charbonnier-smoothed if the options say so)
};

struct EnergyTerms {
  double energy = 0;        // what Evaluate returns: sum of weight * smooth over the terms
  double data_exact = 0;    // sum of Delta E over all pixels of all views (unweighted)
  double smooth_exact = 0;  // sum of the pairwise terms' |v_j - v_i| (unweighted, normalised)
  std::int64_t pixels = 0;
  double mean_delta_e = 0;  // data_exact / pixels
  std::vector<double> view_mean_delta_e;
  std::vector<TermValue> terms;  // every term of the energy, in order
  double exact_energy() const;   // sum of weight * exact over the terms
};

class FitObjective;

// The parameters of an evaluation: one temperature (K) and density (m^-3) per active voxel, and
// the exposure.
struct FitParameters {
  const std::vector<double>& t;
  const std::vector<double>& n;
  double s;
};

// A neighbour pair's curvature in the energy's Gauss-Newton model (FitObjective::
// PairwiseGaussNewton): with respect to the pair's difference in temperature (per kelvin squared)
// and in ln density.
struct PairCurvature {
  double tt = 0, nn = 0;
};

// Where a term adds its weighted gradient: per active voxel, and the exposure. Null members are
// not wanted.
struct FitGradient {
  std::vector<double>* d_t = nullptr;
  std::vector<double>* d_n = nullptr;
  double* d_s = nullptr;
  bool wanted() const { return d_t || d_n || d_s; }
};

// One term of the energy. Stateless apart from what its constructor precomputes; Evaluate may be
// called from one thread at a time.
class EnergyTerm {
 public:
  virtual ~EnergyTerm() = default;
  virtual std::string name() const = 0;  // "data", "pairwise temperature", "pairwise density"
  virtual double weight() const = 0;
  // The term's exact and smoothed values (unweighted) at `x`; adds weight * d(smooth)/dx to
  // `gradient`. `stats` (data terms) gets the per-view figures.
  virtual TermValue Evaluate(const FitParameters& x, const FitGradient& gradient,
                             EnergyTerms* stats) const = 0;
  // Coordinate descent (the paper's algorithms): the exact, unweighted part of the term that
  // involves active voxel `a` (0 for terms that are not sums over voxels; see local()).
  virtual bool local() const { return false; }
  virtual double Local(const FitParameters& x, std::uint32_t a) const { return 0.0; }
  // FitObjective::PairwiseGaussNewton: a pairwise term adds its weighted curvature per neighbour
  // pair into `pairs` (one entry per pair); other terms add nothing.
  virtual void AddPairCurvature(const FitParameters& x, std::vector<PairCurvature>* pairs) const {}
};

// The objective over a fixed set of active voxels.
class FitObjective {
 public:
  // `active`: flat voxel indices of the unknowns (no repeats, inside the grid). Views must have
  // rays and 3-channel images of their camera's size. Throws InputError naming the
  // problem.
  FitObjective(const GridGeometry& grid, std::vector<std::uint32_t> active,
               std::vector<FitView> views, const AbsorptionModel& absorption,
               const RenderOptions& render, const ObjectiveOptions& options);
  ~FitObjective();
  FitObjective(const FitObjective&) = delete;  // its terms refer to it
  FitObjective& operator=(const FitObjective&) = delete;

  std::size_t num_active() const { return active_.size(); }
  const std::vector<std::uint32_t>& active() const { return active_; }
  const GridGeometry& grid() const { return grid_; }
  const ObjectiveOptions& options() const { return options_; }
  const std::vector<FitView>& views() const { return views_; }
  double n_min() const { return n_min_; }
  double n_max() const { return n_max_; }
  // Pairs (i, j), i < j, of active indices that are 18-neighbours.
  const std::vector<std::pair<std::uint32_t, std::uint32_t>>& neighbour_pairs() const {
    return pairs_;
  }

  // The energy's terms, in the order they are evaluated (the data term first).
  const std::vector<std::unique_ptr<EnergyTerm>>& terms() const { return terms_; }

  // Not safe to call concurrently on one objective (it owns one renderer).
  // E at temperatures `t` and densities `n` (one per active voxel) and exposure `s`: the sum of
  // every term. With gradient pointers non-null, also dE/dt, dE/dn (per active voxel) and dE/ds.
  // Values outside the bounds are allowed (the energy is defined for any T >= 0, n >= 0, s > 0;
  // in the density pairwise term a density below n_min() counts as n_min()); NaN inputs throw.
  EnergyTerms Evaluate(const std::vector<double>& t, const std::vector<double>& n, double s,
                       std::vector<double>* d_t = nullptr, std::vector<double>* d_n = nullptr,
                       double* d_s = nullptr) const;

  // Only the data term, per view, and the rendered linear images (for reports and exposure
  // searches that hold the volume fixed): renders once, then scores any exposure cheaply.
  struct Renders {
    std::vector<ImageF> linear;  // per view
  };
  Renders Render(const std::vector<double>& t, const std::vector<double>& n) const;
  // Puts the volume at `t`, `n` into every view's renderer (what Render does before rendering);
  // throws InputError for a wrong count or a non-finite value.
  void UploadVolume(const std::vector<double>& t, const std::vector<double>& n) const;
  // Sum of Delta E over all views at exposure s for renders made by Render().
  double DataTermAt(const Renders& renders, double s) const;

  // The data's Gauss-Newton curvature per active voxel (fitting/uncertainty.h uses it). J is the
  // derivative of every pixel's CIELab value (the data term's residuals, 3 per pixel of every view)
  // with respect to each active voxel's temperature (K) and natural-log density; the result is the
  // voxel's diagonal block of J^T J, its three pairs (T, T), (T, ln n), (ln n, ln n), exact
  // (FireRenderer::RenderCurvature: one render and one curvature pass per view; until 2026-11-26 a
  // Hutchinson estimate from 16 random probes, one adjoint pass per view each, with a relative
  // error of about 35%). Black rendered pixels (their rays cross no emitting medium) are not marched.
  // Also the residuals over fire pixels (rendered or recorded with L* above 1), from which a noise
  // level follows, two ways: their sum of squares (noise and model error together), and half the
  // squared differences between the residuals of fire pixels side by side in a row or a column
  // (the successive-difference estimate of a variance: noise that is independent from pixel to
  // pixel passes into it whole, while an error that changes slowly across the image, as what a
  // model cannot hold mostly does, cancels in it). A Bayer view's residuals are the data term's,
  // through its mosaic, and its differences are taken between fire pixels three apart in a row or
  // a column, beyond the demosaicing's reach: neighbours interpolated from the same sites share
  // their noise, and their differences would hide it. Its Jacobians are each pixel's own, as if
  // it had measured its three channels (the demosaicing's coupling of neighbouring pixels is left
  // out). Measured on the main job's 13 Bayer frame sets (BENCHMARKS.md, "Fitting the mosaic the
  // camera recorded") against two other choices: this one holds 67 to 74% (rings) and 70 to 77%
  // (free voxels) of the visible voxels within one sigma; differences of neighbours give 56 to
  // 62% and 66 to 74%, and Jacobians of the measured channel only 84 to 91% and 79 to 86%.
  struct Curvature {
    std::vector<double> tt, tn, nn;  // per active voxel
    double residual_sq = 0;
    std::int64_t residuals = 0;    // 3 per fire pixel
    double difference_sq = 0;      // sum of |r_p - r_q|^2 / 2 over neighbouring fire pixels
    std::int64_t differences = 0;  // 3 per pair
  };
  Curvature DataCurvature(const std::vector<double>& t, const std::vector<double>& n,
                          double s) const;

  // The energy's Gauss-Newton model, for a solver of few parameters that many voxels share (a
  // tied fit's rings: fit.cc's Levenberg-Marquardt), which builds J^T J over its own parameters.
  //
  // The data term, ray by ray (DataGaussNewton): at (t, n, s) every view is rendered, and each
  // pixel p gets its residual r_p (the Lab of the render less the recorded Lab, the data term's: a
  // Bayer view's through its mosaic) and the data term's iteratively reweighted least-squares
  // weight w_p = w_am rho'(|r_p|) / |r_p| (rho the smoothed distance of ObjectiveOptions::
  // smooth_delta_e; its epsilon taken at least 1e-3 where it is 0), so that w_p J_p^T r_p summed
  // over the pixels is the data term's gradient and w_p J_p^T J_p the Gauss-Newton part of its
  // curvature (rho' / |r| bounds rho'' from above: the model is never flatter than the term).
  // `visit` gets every pixel whose ray crosses medium, from several threads at once: sqrt(w_p)
  // r_p, sqrt(w_p) d r_p / d ln s, and for each active voxel the ray crosses its index into
  // active() and sqrt(w_p) times the 3 x 2 Jacobian of r_p with respect to its (T in kelvin, ln n).
  // A Bayer view's Jacobians are each pixel's own, as if it had measured its three channels
  // (DataCurvature's approximation): the model's curvature, not the gradient, is approximate there.
  struct PixelRows {
    std::size_t view = 0, pixel = 0;
    Eigen::Vector3d residual = Eigen::Vector3d::Zero();
    Eigen::Vector3d d_log_s = Eigen::Vector3d::Zero();
    std::vector<std::uint32_t> active;
    std::vector<Eigen::Matrix<double, 3, 2>> d;
  };
  using PixelRowsVisitor = std::function<void(const PixelRows&)>;
  void DataGaussNewton(const std::vector<double>& t, const std::vector<double>& n, double s,
                       const PixelRowsVisitor& visit) const;
  // The pairwise terms' share: for every neighbour pair (a, b) of active indices, a < b, the
  // iteratively reweighted curvature of the weighted pairwise terms with respect to the pair's
  // difference, T_b - T_a (per kelvin squared) and ln n_b - ln n_a: the pair's part of the energy
  // is then h_t (dT)^2 / 2 + h_n (d ln n)^2 / 2 to second order, in the same sense as the data
  // term's (rho' / |x| of each Charbonnier; 0 where a term is absent or a density is below the
  // range's lowest, where the density term is flat). One entry per neighbour pair, in
  // neighbour_pairs()' order.
  std::vector<PairCurvature> PairwiseGaussNewton(const std::vector<double>& t,
                                                 const std::vector<double>& n) const;

  // Coordinate descent (the paper's algorithms), which render once per move and score exposures
  // on that render (DataTermAt):
  // the data term's weighted value for its exact value `data_exact`;
  double WeightedData(double data_exact) const;
  // the weighted sum of the local terms' parts that involve active voxel `a`;
  double LocalEnergy(const FitParameters& x, std::uint32_t a) const;
  // the exact energy at x when the data term's exact value is already known.
  double EnergyWithData(double data_exact, const FitParameters& x) const;
  // Normalisations used by the pairwise term.
  double NormaliseT(double t) const;
  double NormaliseN(double n) const;
  // The active neighbours of active voxel a: [begin, end) of indices into active().
  const std::uint32_t* neighbours_begin(std::uint32_t a) const {
    return neighbour_list_.data() + neighbour_start_[a];
  }
  const std::uint32_t* neighbours_end(std::uint32_t a) const {
    return neighbour_list_.data() + neighbour_start_[a + 1];
  }
  // View v's Bayer model when the data term uses one (FitView::mosaic and
  // ObjectiveOptions::model_mosaic), else null.
  const BayerRecord* mosaic(std::size_t view) const {
    return options_.model_mosaic ? views_[view].mosaic.get() : nullptr;
  }
  bool any_mosaic() const;
  // The renderer of view v (one per distinct camera response; the data term's use); not safe
  // concurrently.
  FireRenderer& renderer(std::size_t view) const { return *renderers_[view_renderer_[view]]; }
  const std::vector<std::vector<Eigen::Vector3f>>& target_lab() const { return target_lab_; }
  // The active index of flat voxel v, or -1 for a voxel that is not active.
  std::int32_t active_index(std::size_t v) const { return active_index_[v]; }

 private:
  GridGeometry grid_;
  std::vector<std::uint32_t> active_;
  std::vector<std::int32_t> active_index_;  // per voxel of the grid: its active index, or -1
  std::vector<FitView> views_;
  ObjectiveOptions options_;
  double n_min_ = 0, n_max_ = 0;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> pairs_;
  std::vector<std::uint32_t> neighbour_start_, neighbour_list_;  // CSR of neighbours per active
  std::vector<std::vector<Eigen::Vector3f>> target_lab_;         // per view, per pixel
  std::vector<std::unique_ptr<FireRenderer>> renderers_;
  std::vector<std::size_t> view_renderer_;  // per view: index into renderers_
  std::vector<std::unique_ptr<EnergyTerm>> terms_;
};

// Lab of what the camera records from linear radiance I at exposure s, c = clamp(s I, 0, 1), and
// its Jacobian d Lab / d I (3x3, row = L, a, b) for the gradient. Pixel errors everywhere in
// flamerig (energies, reports, benchmarks) are colour::DeltaE76 of two such Labs.
Eigen::Vector3d CameraLab(const Eigen::Vector3d& linear_rgb, double exposure,
                          Eigen::Matrix3d* d_lab_d_linear = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_OBJECTIVE_H_
