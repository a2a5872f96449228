#include "pipeline/radiometric_calibration.h"

#include <ceres/ceres.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <opencv2/imgproc.hpp>
#include <random>
#include <set>
#include <sstream>

#include "core/config_reader.h"
#include "core/error.h"
#include "core/format.h"
#include "core/log.h"
#include "fitting/camera_response.h"
#include "pipeline/simulate.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

std::array<int, 4> ReadRegion(const YAML::Node& node, const std::string& where) {
  if (!node || (node.IsScalar() && node.as<std::string>() == "auto")) return {0, 0, 0, 0};
  if (!node.IsSequence() || node.size() != 4)
    throw InputError(where + ": region: 'auto' or [x, y, width, height]");
  std::array<int, 4> r{};
  for (int i = 0; i < 4; ++i) r[i] = node[i].as<int>();
  if (r[0] < 0 || r[1] < 0 || r[2] <= 0 || r[3] <= 0)
    throw InputError(where + ": region: x, y >= 0 and width, height > 0");
  return r;
}

// One shot's image, read and checked against its camera.
struct ShotImage {
  int bits = 8;
  ImageU8 u8;
  ImageU16 u16;
  int width = 0, height = 0, channels = 0;
  double code(int x, int y, int c) const {
    return bits == 8 ? double(u8.at(x, y, c)) : double(u16.at(x, y, c));
  }
};

ShotImage ReadShot(const RadiometricShot& shot, const RigCamera& camera, const std::string& where) {
  ShotImage image;
  image.bits = ReadImage(shot.image, &image.u8, &image.u16);
  image.width = image.bits == 8 ? image.u8.width : image.u16.width;
  image.height = image.bits == 8 ? image.u8.height : image.u16.height;
  image.channels = image.bits == 8 ? image.u8.channels : image.u16.channels;
  if (image.width != camera.model.width() || image.height != camera.model.height())
    throw InputError(where + ": " + shot.image + " is " + std::to_string(image.width) + "x" +
                     std::to_string(image.height) + ", camera " + camera.name + "'s imager is " +
                     std::to_string(camera.model.width()) + "x" +
                     std::to_string(camera.model.height()));
  const int want = camera.radiometry.channels();
  if (image.channels != want)
    throw InputError(where + ": " + shot.image + " has " + std::to_string(image.channels) +
                     " channel(s); camera " + camera.name + "'s model (" +
                     camera.radiometry.spectral.Describe() + ") has " + std::to_string(want));
  return image;
}

// The largest connected bright area of an image, shrunk by erode_px: the source's aperture.
std::array<int, 4> FindPatch(const ShotImage& image, int erode_px, const std::string& where) {
  cv::Mat value(image.height, image.width, CV_32F);
  std::vector<float> all;
  all.reserve(std::size_t(image.width) * image.height);
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      double v = 0;
      for (int c = 0; c < image.channels; ++c) v = std::max(v, image.code(x, y, c));
      value.at<float>(y, x) = float(v);
      all.push_back(float(v));
    }
  auto quantile = [&](double q) {
    std::vector<float> copy = all;
    auto it = copy.begin() + std::ptrdiff_t(q * double(copy.size() - 1));
    std::nth_element(copy.begin(), it, copy.end());
    return double(*it);
  };
  const double median = quantile(0.5), peak = quantile(0.995);
  const double full = image.bits == 8 ? 255.0 : 65535.0;
  if (!(peak - median > 0.002 * full))
    throw InputError(where +
                     ": no bright source patch in the camera's brightest shot (its 99.5th "
                     "percentile is " +
                     FormatNumber(peak, 4) + ", its median " + FormatNumber(median, 4) +
                     "): give `region: [x, y, width, height]`");
  cv::Mat mask = value > float(0.5 * (median + peak));
  cv::Mat labels, stats, centroids;
  const int n = cv::connectedComponentsWithStats(mask, labels, stats, centroids, 8);
  int best = 0;
  for (int i = 1; i < n; ++i)
    if (best == 0 || stats.at<int>(i, cv::CC_STAT_AREA) > stats.at<int>(best, cv::CC_STAT_AREA))
      best = i;
  cv::Mat component = labels == best;
  if (erode_px > 0)
    cv::erode(
        component, component,
        cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * erode_px + 1, 2 * erode_px + 1)));
  // The patch: the largest axis-aligned box inside the eroded area around its centroid, taken
  // as the bounding box of the eroded area shrunk until every pixel lies in it (a disc's
  // inscribed square).
  const cv::Rect box = cv::boundingRect(component);
  cv::Rect r = box;
  while (r.width > 2 && r.height > 2 && cv::countNonZero(component(r)) < r.area()) {
    r.x += 1;
    r.y += 1;
    r.width -= 2;
    r.height -= 2;
  }
  if (r.area() < 25 || cv::countNonZero(component(r)) < r.area())
    throw InputError(where + ": the source patch found is too small (" +
                     std::to_string(std::max(0, r.area())) +
                     " px after shrinking by erode_px): give `region: [x, y, width, height]`");
  return {r.x, r.y, r.width, r.height};
}

// The patch's mean code and the share of its pixels at the saturation level, per channel.
void PatchStatistics(const ShotImage& image, const std::array<int, 4>& region, double saturation,
                     Eigen::Vector3d* mean, Eigen::Vector3d* saturated) {
  mean->setZero();
  saturated->setZero();
  const int n = region[2] * region[3];
  for (int y = region[1]; y < region[1] + region[3]; ++y)
    for (int x = region[0]; x < region[0] + region[2]; ++x)
      for (int c = 0; c < image.channels; ++c) {
        const double v = image.code(x, y, c);
        (*mean)[c] += v;
        if (v >= saturation - 0.5) (*saturated)[c] += 1;
      }
  *mean /= double(n);
  *saturated /= double(n);
}

// The median code of the pixels at least 8 px outside the patch's box (the dark frame).
double DarkLevel(const ShotImage& image, const std::array<int, 4>& region) {
  std::vector<double> values;
  const int margin = 8;
  for (int y = 0; y < image.height; y += 2)
    for (int x = 0; x < image.width; x += 2) {
      if (x > region[0] - margin && x < region[0] + region[2] + margin && y > region[1] - margin &&
          y < region[1] + region[3] + margin)
        continue;
      for (int c = 0; c < image.channels; ++c) values.push_back(image.code(x, y, c));
    }
  if (values.empty()) return 0;
  auto mid = values.begin() + std::ptrdiff_t(values.size() / 2);
  std::nth_element(values.begin(), mid, values.end());
  return *mid;
}

// One observation: a shot's channel mean code, explained by black + encode(s * g * eps * B).
struct CodeResidual {
  CodeResidual(const CameraRadiometry& model, const CameraRadiometry::Decoding& decoding, double x,
               double code)
      : model(model), decoding(decoding), x(x), code(code) {}
  bool operator()(const double* black, const double* gain, const double* gamma,
                  double* residual) const {
    CameraRadiometry::Decoding d = decoding;
    d.black = black[0];
    if (!(d.black < d.saturation)) return false;
    const double signal = std::min(1.0, std::max(0.0, gain[0] * x));
    double e = 0;
    if (d.transfer == TransferFunction::kGamma) {
      if (!(gamma[0] > 0.05)) return false;
      e = d.black + std::pow(signal, 1.0 / gamma[0]) * (d.saturation - d.black);
    } else {
      e = model.Encode(signal, d);
    }
    residual[0] = e - code;
    return true;
  }
  const CameraRadiometry& model;
  CameraRadiometry::Decoding decoding;
  double x, code;
};

struct Observation {
  std::size_t shot;  // index into the result's shots
  int channel;
  double x;     // exposure * emissivity * B_c(T): the signal per unit gain
  double code;  // the patch's mean code
  bool for_gain;
};

void CalibrateCamera(const RigCamera& camera, const std::vector<std::size_t>& shot_indices,
                     const RadiometricShots& shots, const RadiometricOptions& options,
                     RadiometricCalibration* out, CameraRadiometricResult* result) {
  const CameraRadiometry& model = camera.radiometry;
  const int channels = model.channels();
  const std::string where = shots.path + ": camera " + camera.name;
  result->camera = camera.name;
  result->channels = channels;
  result->before = model;
  result->shots = int(shot_indices.size());

  std::vector<ShotImage> images;
  for (std::size_t i : shot_indices)
    images.push_back(ReadShot(shots.shots[i], camera, where + ", shot " + std::to_string(i)));
  const int bits = images.front().bits;
  for (std::size_t k = 0; k < images.size(); ++k)
    if (images[k].bits != bits)
      throw InputError(where + ": " + shots.shots[shot_indices[k]].image + " is " +
                       std::to_string(images[k].bits) + "-bit, its first shot " +
                       std::to_string(bits) + "-bit");
  CameraRadiometry::Decoding decoding = model.DecodingFor(bits);
  // The camera's channels of a black body with unit gains, in the renderer's units: one response
  // for all its shots.
  const auto response = ChannelResponse::ForCamera(model);
  auto unit_gain_blackbody = [&](double temperature_k) -> Eigen::Vector3d {
    return response->Blackbody(temperature_k).cwiseQuotient(response->gain());
  };

  // The patch: given, or from the brightest shot.
  std::array<int, 4> region = shots.region;
  if (region[2] == 0) {
    std::size_t brightest = 0;
    double best = -1;
    for (std::size_t k = 0; k < images.size(); ++k) {
      const RadiometricShot& s = shots.shots[shot_indices[k]];
      const double level = s.exposure * unit_gain_blackbody(s.temperature_k).maxCoeff();
      if (level > best) best = level, brightest = k;
    }
    region = FindPatch(images[brightest], options.erode_px,
                       where + ", " + shots.shots[shot_indices[brightest]].image);
  }
  result->region = region;

  std::vector<Observation> observations;
  std::vector<double> temperatures;
  const std::size_t first_shot = out->shots.size();
  for (std::size_t k = 0; k < images.size(); ++k) {
    RadiometricShotResult r;
    r.shot = shots.shots[shot_indices[k]];
    const std::array<int, 4> patch = r.shot.region[2] > 0 ? r.shot.region : region;
    if (patch[0] + patch[2] > images[k].width || patch[1] + patch[3] > images[k].height)
      throw InputError(
          where + ": region [" + std::to_string(patch[0]) + ", " + std::to_string(patch[1]) + ", " +
          std::to_string(patch[2]) + ", " + std::to_string(patch[3]) + "] leaves " + r.shot.image +
          " (" + std::to_string(images[k].width) + "x" + std::to_string(images[k].height) + ")");
    r.patch_pixels = patch[2] * patch[3];
    Eigen::Vector3d saturated;
    PatchStatistics(images[k], patch, decoding.saturation, &r.mean_code, &saturated);
    if (k == 0) result->dark_level_dn = DarkLevel(images[k], patch);
    const double emissivity =
        shots.source == RadiometricShots::Source::kBlackbody ? shots.emissivity : 1.0;
    const Eigen::Vector3d b = unit_gain_blackbody(r.shot.temperature_k);
    for (int c = 0; c < channels; ++c) {
      Observation o;
      o.shot = out->shots.size();
      o.channel = c;
      o.x = r.shot.exposure * emissivity * b[c];
      o.code = r.mean_code[c];
      o.for_gain = true;
      const double signal = model.Signal(o.code, decoding);
      if (!(o.x > 0)) {
        // The sRGB observer's blue of a cool black body lies outside the sRGB gamut: the model
        // clips it to black, and the channel says nothing about the gain.
        r.left_out[c] = "the model predicts no signal (a negative linear sRGB value)";
        continue;
      }
      if (saturated[c] > options.max_saturated_fraction) {
        r.left_out[c] = "saturated (" + FormatNumber(100 * saturated[c], 3) + "% of the patch)";
        continue;  // a clipped mean says nothing exact, not even about the black level
      }
      // Dark by the model's black level: in the fit only when the black level is fitted.
      o.for_gain = signal >= options.min_signal;
      observations.push_back(o);
    }
    if (std::find(temperatures.begin(), temperatures.end(), r.shot.temperature_k) ==
        temperatures.end())
      temperatures.push_back(r.shot.temperature_k);
    out->shots.push_back(std::move(r));
  }
  std::sort(temperatures.begin(), temperatures.end());
  result->temperatures_k = temperatures;

  // What the data allow: per channel, the signals the gains see.
  bool black_identifiable = options.fit_black_level;
  int gamma_levels = 1 << 30;
  for (int c = 0; c < channels; ++c) {
    std::vector<double> xs, all;
    for (const Observation& o : observations)
      if (o.channel == c) {
        all.push_back(o.x);
        if (o.for_gain) xs.push_back(o.x);
      }
    if (xs.empty()) {
      std::map<std::string, int> reasons;
      for (std::size_t k = first_shot; k < out->shots.size(); ++k) {
        const std::string& why = out->shots[k].left_out[std::size_t(c)];
        ++reasons[why.substr(0, why.find(" ("))];
      }
      std::string list;
      for (const auto& [why, count] : reasons)
        list += (list.empty() ? "" : ", ") + std::to_string(count) + " " + why;
      std::string remedy = "film the source so that every channel lies between " +
                           FormatNumber(options.min_signal, 4) + " of full scale and saturation";
      if (reasons.size() == 1 &&
          reasons.begin()->first.rfind("the model predicts no signal", 0) == 0) {
        // A cool black body's blue lies outside the sRGB gamut: from which temperature it does not.
        double from = 0;
        for (double t = 1000; t <= 20000 && from == 0; t += 50)
          if (unit_gain_blackbody(t)[c] > 0) from = t;
        remedy = "the model gives a black body at " + FormatNumber(temperatures.front(), 5) +
                 (temperatures.size() > 1 ? " to " + FormatNumber(temperatures.back(), 5) : "") +
                 " K no signal in that channel (the sRGB observer's blue of a cool source is "
                 "outside the sRGB gamut)" +
                 (from > 0 ? ": film the source at " + FormatNumber(from, 5) + " K or hotter"
                           : std::string()) +
                 ", or give the camera's spectral curves";
      }
      throw InputError(where + ": no usable shot for channel " + std::to_string(c) + " (" + list +
                       "): " + remedy);
    }
    std::sort(all.begin(), all.end());
    if (all.empty() || !(all.back() >= 1.5 * all.front())) black_identifiable = false;
    int levels = 1;
    std::sort(xs.begin(), xs.end());
    for (std::size_t i = 1; i < xs.size(); ++i)
      if (xs[i] > 1.2 * xs[i - 1]) ++levels;
    gamma_levels = std::min(gamma_levels, levels);
  }
  const bool gamma_identifiable =
      options.fit_gamma && decoding.transfer == TransferFunction::kGamma && gamma_levels >= 3;
  // The dark pixels around the source against the black level the fit holds: a black level that
  // is wrong by tens of DN made gains 5 times off that fitted their shots to 1e-13 DN.
  {
    const double full = decoding.saturation - decoding.black, dark = result->dark_level_dn;
    double darkest = decoding.saturation;
    for (const Observation& o : observations) darkest = std::min(darkest, o.code);
    const bool disagrees = std::abs(dark - decoding.black) > std::max(2.0, 0.002 * full);
    const bool plausible = dark >= 0 && dark < darkest && dark <= decoding.black + 0.1 * full;
    const std::string says = "the dark pixels around the source read " + FormatNumber(dark, 4) +
                             " DN, the model's black level is " + FormatNumber(decoding.black, 4) +
                             " DN";
    if (options.fit_black_level && !black_identifiable) {
      if (disagrees && plausible) {
        result->notes.push_back(
            "black level " + FormatNumber(dark, 4) +
            " DN, the dark pixels' median: the shots do not span signals a factor 1.5 apart in "
            "every channel to fit it, and " +
            says);
        decoding.black = dark;
        result->black_level_from_dark = true;
        for (Observation& o : observations)
          o.for_gain = model.Signal(o.code, decoding) >= options.min_signal;
      } else {
        result->notes.push_back("black level held at " + FormatNumber(decoding.black, 4) +
                                " DN: the shots do not span signals a factor 1.5 apart in every "
                                "channel");
        if (disagrees)
          result->warnings.push_back(says +
                                     ", too bright to be a black level: is the background "
                                     "lit? The gains rest on the model's black level");
      }
    } else if (!options.fit_black_level && disagrees) {
      result->warnings.push_back(says +
                                 " (held): if the background is dark, the held level is "
                                 "wrong and the gains with it; let the calibration fit it, or set "
                                 "the camera's black_level");
    }
  }
  if (options.fit_gamma && decoding.transfer == TransferFunction::kGamma && !gamma_identifiable)
    result->notes.push_back("gamma held at " + FormatNumber(model.gamma, 4) +
                            ": fewer than three distinct signal levels");

  // The fit of the observations of the shots not in `outliers`: black level, gains and gamma.
  struct Fitted {
    double black = 0, gamma = 1, gains[3] = {1, 1, 1};
    double rms = 0;                          // DN, over the observations fitted
    std::map<std::size_t, double> shot_rms;  // per shot index in out->shots, DN
  };
  auto solve = [&](const std::set<std::size_t>& outliers) {
    Fitted f;
    f.black = decoding.black;
    f.gamma = model.gamma;
    // Start: the model's black level and the least-squares gains of the decoded signals.
    for (int c = 0; c < 3; ++c) f.gains[c] = model.gain[c];
    for (int c = 0; c < channels; ++c) {
      double xy = 0, xx = 0;
      for (const Observation& o : observations)
        if (o.channel == c && o.for_gain && !outliers.count(o.shot)) {
          xy += o.x * model.Signal(o.code, decoding);
          xx += o.x * o.x;
        }
      if (xx > 0 && xy > 0) f.gains[c] = xy / xx;
    }
    ceres::Problem problem;
    std::vector<const Observation*> fitted_observations;
    for (const Observation& o : observations) {
      if ((!o.for_gain && !black_identifiable) || outliers.count(o.shot)) continue;
      auto* cost = new ceres::NumericDiffCostFunction<CodeResidual, ceres::CENTRAL, 1, 1, 1, 1>(
          new CodeResidual(model, decoding, o.x, o.code));
      problem.AddResidualBlock(cost, nullptr, &f.black, &f.gains[o.channel], &f.gamma);
      fitted_observations.push_back(&o);
    }
    if (!black_identifiable) {
      problem.SetParameterBlockConstant(&f.black);
    } else {
      problem.SetParameterLowerBound(&f.black, 0, 0.0);
      problem.SetParameterUpperBound(&f.black, 0, decoding.saturation - 1);
    }
    if (!gamma_identifiable) {
      problem.SetParameterBlockConstant(&f.gamma);
    } else {
      problem.SetParameterLowerBound(&f.gamma, 0, 0.2);
      problem.SetParameterUpperBound(&f.gamma, 0, 5.0);
    }
    for (int c = 0; c < channels; ++c) problem.SetParameterLowerBound(&f.gains[c], 0, 1e-12);
    ceres::Solver::Options solver;
    solver.max_num_iterations = 100;
    solver.function_tolerance = 1e-12;
    solver.parameter_tolerance = 1e-12;
    solver.num_threads = 1;
    ceres::Solver::Summary summary;
    ceres::Solve(solver, &problem, &summary);
    if (!summary.IsSolutionUsable())
      throw DataError(where + ": the radiometric fit failed: " + summary.message);
    // Every shot's residuals in the fitted model, the left-out shots' included.
    std::map<std::size_t, std::pair<double, int>> per_shot;
    double sum = 0;
    for (const Observation& o : observations) {
      if (!o.for_gain && !black_identifiable) continue;
      double e = 0;
      CodeResidual(model, decoding, o.x, o.code)(&f.black, &f.gains[o.channel], &f.gamma, &e);
      per_shot[o.shot].first += e * e;
      per_shot[o.shot].second += 1;
      if (!outliers.count(o.shot)) sum += e * e;
    }
    f.rms = fitted_observations.empty() ? 0 : std::sqrt(sum / double(fitted_observations.size()));
    for (const auto& [shot, entry] : per_shot)
      f.shot_rms[shot] = std::sqrt(entry.first / entry.second);
    return f;
  };

  // A shot that disagrees with all the others (a wrong image, a capped lens, a mistyped exposure)
  // would pull every gain: it is left out, with a warning naming it, when leaving it out divides
  // the fit's RMS by `outlier_ratio` or more. Systematic misfit (a wrong spectral model) spreads
  // over all shots and leaves none out. At most a quarter of the shots, and 3 must remain.
  std::set<std::size_t> outliers;
  Fitted fit = solve(outliers);
  const double full_scale = decoding.saturation - decoding.black;
  while (4 * (outliers.size() + 1) <= images.size() && images.size() - outliers.size() > 3 &&
         fit.rms > 0.001 * full_scale) {
    std::size_t worst = 0;
    double worst_rms = -1;
    for (const auto& [shot, rms] : fit.shot_rms)
      if (!outliers.count(shot) && rms > worst_rms) worst = shot, worst_rms = rms;
    std::set<std::size_t> trial = outliers;
    trial.insert(worst);
    // Every channel must keep a shot for its gain.
    bool keeps_every_channel = true;
    for (int c = 0; c < channels; ++c) {
      bool kept = false;
      for (const Observation& o : observations)
        kept |= o.channel == c && o.for_gain && !trial.count(o.shot);
      keeps_every_channel &= kept;
    }
    if (!keeps_every_channel) break;
    const Fitted without = solve(trial);
    if (!(without.rms * options.outlier_ratio <= fit.rms)) break;
    const RadiometricShot& s = out->shots[worst].shot;
    result->warnings.push_back(
        "shot " + s.image + " (" + FormatNumber(s.temperature_k, 4) + " K, exposure " +
        FormatNumber(s.exposure, 4) + ") left out: its codes lie " +
        FormatNumber(without.shot_rms.at(worst), 3) +
        " DN (rms) from what the other shots predict, which agree to " +
        FormatNumber(without.rms, 3) +
        " DN: a wrong image, a covered lens or a wrong exposure in the shots file?");
    for (int c = 0; c < channels; ++c)
      if (out->shots[worst].left_out[std::size_t(c)].empty())
        out->shots[worst].left_out[std::size_t(c)] = "an outlier (" +
                                                     FormatNumber(without.shot_rms.at(worst), 3) +
                                                     " DN from the others' fit)";
    outliers = trial;
    fit = without;
  }
  if (fit.rms > options.max_rms * full_scale) {
    std::size_t worst = 0;
    double worst_rms = -1;
    for (const auto& [shot, rms] : fit.shot_rms)
      if (!outliers.count(shot) && rms > worst_rms) worst = shot, worst_rms = rms;
    throw DataError(where + ": the model does not explain the shots: their codes lie " +
                    FormatNumber(fit.rms, 4) + " DN (rms) from it, " +
                    FormatNumber(100 * fit.rms / full_scale, 3) + "% of full scale (at most " +
                    FormatNumber(100 * options.max_rms, 4) + "%); the worst is " +
                    out->shots[worst].shot.image + " (" + FormatNumber(worst_rms, 4) +
                    " DN). Check the shots' images and exposures, and the "
                    "model's transfer function, bit depth and spectral sensitivity");
  }
  const double black = fit.black, gamma = fit.gamma;
  const double* gains = fit.gains;

  CameraRadiometry after = model;
  after.black_level = black;
  after.gamma = gamma;
  for (int c = 0; c < 3; ++c) after.gain[c] = gains[channels == 1 ? 0 : c];
  if (shots.source == RadiometricShots::Source::kLamp) {
    // Ratios only: keep the model's mean gain.
    const double scale = model.gain.head(channels).mean() / after.gain.head(channels).mean();
    after.gain *= scale;
    result->notes.push_back(
        "lamp: the gains' ratios are calibrated, their scale is the model's "
        "(fit the exposure, or calibrate the scale with a black body)");
  }
  after.Validate(where);
  result->after = after;
  result->fitted_black_level = black_identifiable;
  result->fitted_gamma = gamma_identifiable;

  // Residuals and the spectral check, in the fitted model.
  CameraRadiometry::Decoding fitted = after.DecodingFor(bits);
  double sum = 0;
  std::map<double, std::array<std::pair<double, double>, 3>> ratio;  // per T: sum, count
  for (const Observation& o : observations) {
    RadiometricShotResult& r = out->shots[o.shot];
    const double g = gains[o.channel];
    const double model_code = after.Encode(g * o.x, fitted);
    r.model_code[o.channel] = model_code;
    if (outliers.count(o.shot)) continue;  // its reason is said
    if (g * o.x < options.min_signal)
      r.left_out[std::size_t(o.channel)] =
          !o.for_gain && !black_identifiable
              ? "too dark for the gain (signal " + FormatNumber(g * o.x, 3) + "), left out"
              : "dark (signal " + FormatNumber(g * o.x, 3) + "): weighs on the black level";
    sum += (model_code - o.code) * (model_code - o.code);
    ++result->residuals;
    if (o.for_gain && g * o.x >= options.min_signal) {
      auto& entry = ratio[r.shot.temperature_k][std::size_t(o.channel)];
      entry.first += after.Signal(o.code, fitted) / std::min(1.0, g * o.x);
      entry.second += 1;
    }
  }
  result->rms_dn = result->residuals > 0 ? std::sqrt(sum / result->residuals) : 0;
  if (ratio.size() >= 2) {
    const char* names = channels == 1 ? "M" : "RGB";
    for (int c = 0; c < channels; ++c) {
      double lo = 1e300, hi = -1e300, worst = 0, t_lo = 0, t_hi = 0;
      for (const auto& [t, entry] : ratio) {
        if (entry[std::size_t(c)].second == 0) continue;
        const double q = entry[std::size_t(c)].first / entry[std::size_t(c)].second;
        worst = std::max(worst, std::abs(q - 1));
        if (q < lo) lo = q, t_lo = t;
        if (q > hi) hi = q, t_hi = t;
      }
      result->spectral_mismatch[c] = worst;
      if (worst > options.max_spectral_mismatch)
        result->warnings.push_back(
            std::string("channel ") + names[c] + ": measured / model is " + FormatNumber(lo, 4) +
            " at " + FormatNumber(t_lo, 4) + " K but " + FormatNumber(hi, 4) + " at " +
            FormatNumber(t_hi, 4) +
            " K: the camera's spectral "
            "sensitivity is not what its model says (" +
            model.spectral.Describe() +
            "); gains cannot fix that, and fitted temperatures will be biased: give the "
            "sensor's measured curves (sensitivity_file)");
    }
  } else {
    result->notes.push_back(
        "one source temperature: the spectral sensitivity is not checked "
        "(film the source at two temperatures or more)");
  }
}

}  // namespace

void RadiometricOptions::Validate() const {
  auto fail = [](const std::string& field, const std::string& rule) {
    throw InputError("radiometric calibration: " + field + ": " + rule);
  };
  if (erode_px < 0 || erode_px > 100) fail("erode_px", "must be in 0..100");
  if (!(max_saturated_fraction >= 0 && max_saturated_fraction < 1))
    fail("max_saturated_fraction", "must be in [0, 1)");
  if (!(min_signal >= 0 && min_signal < 1)) fail("min_signal", "must be in [0, 1)");
  if (!(max_spectral_mismatch > 0)) fail("max_spectral_mismatch", "must be > 0");
  if (!(outlier_ratio > 1)) fail("outlier_ratio", "must be > 1");
  if (!(max_rms > 0)) fail("max_rms", "must be > 0");
}

RadiometricShots RadiometricShots::Load(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
    RejectDuplicateKeys(root, path);
  } catch (const YAML::BadFile&) {
    throw IoError("cannot read the shots file " + path);
  } catch (const YAML::Exception& e) {
    throw InputError(path + ": not YAML: " + e.what());
  }
  RadiometricShots s;
  s.path = path;
  const fs::path base = fs::path(path).parent_path();
  // A number, or an error naming the field and what it holds (yaml-cpp says only "bad
  // conversion" at a line; `nan` unquoted is not YAML's NaN, `.nan`).
  auto number = [](const YAML::Node& node, const std::string& field) {
    try {
      return node.as<double>();
    } catch (const YAML::Exception&) {
      throw InputError(field + ": '" + (node.IsScalar() ? node.Scalar() : std::string("a list")) +
                       "' is not a number");
    }
  };
  try {
    // A misspelt key would silently keep its default (an emissivity of 0.98, an automatic region).
    CheckKeys(root, {"source", "region", "exposure_unit_us", "shots"}, path);
    if (root["exposure_unit_us"]) {
      s.exposure_unit_us = number(root["exposure_unit_us"], path + ": exposure_unit_us");
      if (!(s.exposure_unit_us > 0) || !std::isfinite(s.exposure_unit_us))
        throw InputError(path +
                         ": exposure_unit_us: must be a finite time > 0 in microseconds, "
                         "got " +
                         FormatNumber(s.exposure_unit_us, 4));
    }
    if (const YAML::Node source = root["source"]) {
      CheckKeys(source, {"kind", "emissivity"}, path + ": source");
      const std::string kind = source["kind"] ? source["kind"].as<std::string>() : "blackbody";
      if (kind == "blackbody")
        s.source = Source::kBlackbody;
      else if (kind == "lamp")
        s.source = Source::kLamp;
      else
        throw InputError(path + ": source.kind: 'blackbody' or 'lamp', got '" + kind + "'");
      if (source["emissivity"])
        s.emissivity = number(source["emissivity"], path + ": source.emissivity");
      if (!(s.emissivity > 0 && s.emissivity <= 1))
        throw InputError(path + ": source.emissivity: must be in (0, 1], got " +
                         FormatNumber(s.emissivity, 4));
    }
    s.region = ReadRegion(root["region"], path);
    const YAML::Node list = root["shots"];
    if (!list || !list.IsSequence() || list.size() == 0)
      throw InputError(path + ": shots: a list of {camera, image, temperature_k, exposure}");
    for (std::size_t i = 0; i < list.size(); ++i) {
      const YAML::Node n = list[i];
      const std::string where = path + ": shots[" + std::to_string(i) + "]";
      CheckKeys(
          n, {"camera", "image", "temperature_k", "exposure", "exposure_us", "gain_db", "region"},
          where);
      for (const char* key : {"camera", "image", "temperature_k"})
        if (!n[key]) throw InputError(where + ": missing '" + key + "'");
      if (!n["exposure"] == !n["exposure_us"])
        throw InputError(where +
                         ": give one of 'exposure' (the renderer's units) and "
                         "'exposure_us' (the camera's exposure time, with gain_db)");
      if (n["gain_db"] && !n["exposure_us"])
        throw InputError(where + ": 'gain_db' goes with 'exposure_us'");
      RadiometricShot shot;
      shot.camera = n["camera"].as<std::string>();
      const fs::path image = n["image"].as<std::string>();
      shot.image = (image.is_absolute() ? image : base / image).string();
      shot.temperature_k = number(n["temperature_k"], where + ": temperature_k");
      if (n["exposure_us"]) {
        if (!(s.exposure_unit_us > 0))
          throw InputError(where +
                           ": exposure_us needs the file's exposure_unit_us (the "
                           "exposure time at 0 dB that exposure 1 stands for)");
        shot.exposure_us = number(n["exposure_us"], where + ": exposure_us");
        if (n["gain_db"]) shot.gain_db = number(n["gain_db"], where + ": gain_db");
        if (!(shot.exposure_us > 0) || !std::isfinite(shot.exposure_us))
          throw InputError(where + ": exposure_us: must be finite and > 0, got " +
                           FormatNumber(shot.exposure_us, 4));
        if (!(shot.gain_db >= -100 && shot.gain_db <= 100))
          throw InputError(where + ": gain_db: must be in -100..100, got " +
                           FormatNumber(shot.gain_db, 4));
        shot.exposure = shot.exposure_us * std::pow(10.0, shot.gain_db / 20) / s.exposure_unit_us;
      } else {
        shot.exposure = number(n["exposure"], where + ": exposure");
      }
      if (!(shot.temperature_k >= 500 && shot.temperature_k <= 4000))
        throw InputError(where + ": temperature_k: must be in 500..4000 K, got " +
                         FormatNumber(shot.temperature_k, 4));
      if (!(shot.exposure > 0) || !std::isfinite(shot.exposure))
        throw InputError(where + ": exposure: must be finite and > 0, got " +
                         FormatNumber(shot.exposure, 4));
      shot.region = ReadRegion(n["region"], where);
      s.shots.push_back(shot);
    }
  } catch (const YAML::Exception& e) {
    throw InputError(path + ": " + e.what());
  }
  return s;
}

void RadiometricShots::Save(const std::string& path) const {
  const fs::path base = fs::path(path).parent_path();
  YAML::Emitter y;
  y.SetDoublePrecision(10);
  y << YAML::BeginMap << YAML::Key << "source" << YAML::Value << YAML::Flow << YAML::BeginMap
    << YAML::Key << "kind" << YAML::Value << (source == Source::kLamp ? "lamp" : "blackbody");
  if (source == Source::kBlackbody) y << YAML::Key << "emissivity" << YAML::Value << emissivity;
  y << YAML::EndMap;
  auto region_value = [&](const std::array<int, 4>& r) {
    if (r[2] == 0) {
      y << "auto";
    } else {
      y << YAML::Flow << YAML::BeginSeq;
      for (int v : r) y << v;
      y << YAML::EndSeq;
    }
  };
  y << YAML::Key << "region" << YAML::Value;
  region_value(region);
  if (exposure_unit_us > 0) y << YAML::Key << "exposure_unit_us" << YAML::Value << exposure_unit_us;
  y << YAML::Key << "shots" << YAML::Value << YAML::BeginSeq;
  for (const RadiometricShot& s : shots) {
    y << YAML::Flow << YAML::BeginMap << YAML::Key << "camera" << YAML::Value << s.camera
      << YAML::Key << "image" << YAML::Value << fs::relative(s.image, base).string() << YAML::Key
      << "temperature_k" << YAML::Value << s.temperature_k;
    if (s.exposure_us > 0)
      y << YAML::Key << "exposure_us" << YAML::Value << s.exposure_us << YAML::Key << "gain_db"
        << YAML::Value << s.gain_db;
    else
      y << YAML::Key << "exposure" << YAML::Value << s.exposure;
    if (s.region[2] > 0) {
      y << YAML::Key << "region" << YAML::Value;
      region_value(s.region);
    }
    y << YAML::EndMap;
  }
  y << YAML::EndSeq << YAML::EndMap;
  fs::create_directories(base.empty() ? fs::path(".") : base);
  std::ofstream f(path);
  f << "# Radiometric calibration shots (pipeline/radiometric_calibration.h)\n"
    << y.c_str() << "\n";
  if (!f) throw IoError("cannot write " + path);
}

RadiometricCalibration CalibrateRadiometry(const Rig& rig, const RadiometricShots& shots,
                                           const RadiometricOptions& options) {
  options.Validate();
  std::vector<std::vector<std::size_t>> per_camera(rig.cameras.size());
  for (std::size_t i = 0; i < shots.shots.size(); ++i) {
    const RadiometricShot& s = shots.shots[i];
    std::size_t c = 0;
    while (c < rig.cameras.size() && rig.cameras[c].name != s.camera) ++c;
    if (c == rig.cameras.size()) {
      std::string names;
      for (const RigCamera& rc : rig.cameras) names += (names.empty() ? "" : ", ") + rc.name;
      throw InputError(shots.path + ": shots[" + std::to_string(i) + "]: camera '" + s.camera +
                       "' is not in the rig (" + names + ")");
    }
    per_camera[c].push_back(i);
  }
  RadiometricCalibration out;
  out.lamp = shots.source == RadiometricShots::Source::kLamp;
  out.exposure_unit_us = shots.exposure_unit_us;
  for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
    if (per_camera[c].empty()) continue;
    CameraRadiometricResult result;
    CalibrateCamera(rig.cameras[c], per_camera[c], shots, options, &out, &result);
    Log().info("radiometry: {}: gains {} -> {}, black {} -> {}, rms {} DN", result.camera,
               FormatNumber(result.before.gain[0], 4) + "/" +
                   FormatNumber(result.before.gain[1], 4) + "/" +
                   FormatNumber(result.before.gain[2], 4),
               FormatNumber(result.after.gain[0], 4) + "/" + FormatNumber(result.after.gain[1], 4) +
                   "/" + FormatNumber(result.after.gain[2], 4),
               FormatNumber(result.before.black_level, 4),
               FormatNumber(result.after.black_level, 4), FormatNumber(result.rms_dn, 3));
    for (const std::string& w : result.warnings) Log().warn("radiometry: {}: {}", result.camera, w);
    out.cameras.push_back(std::move(result));
  }
  if (out.cameras.empty()) throw InputError(shots.path + ": no shots");
  return out;
}

Rig ApplyRadiometricCalibration(const Rig& rig, const RadiometricCalibration& calibration) {
  Rig out = rig;
  // A lamp's gains hold their ratios, not their scale: its unit would not make a known exposure.
  if (calibration.exposure_unit_us > 0 && !calibration.lamp)
    out.exposure_unit_us = calibration.exposure_unit_us;
  for (const CameraRadiometricResult& r : calibration.cameras)
    for (RigCamera& c : out.cameras)
      if (c.name == r.camera) c.radiometry = r.after;
  return out;
}

std::string RadiometricCalibration::Brief() const {
  std::ostringstream s;
  for (const CameraRadiometricResult& c : cameras) {
    s << c.camera << ": gain";
    for (int i = 0; i < c.channels; ++i) s << (i ? "/" : " ") << FormatNumber(c.after.gain[i], 4);
    s << ", black " << FormatNumber(c.after.black_level, 4) << " DN"
      << (c.fitted_black_level      ? ""
          : c.black_level_from_dark ? " (dark pixels)"
                                    : " (held)");
    if (c.fitted_gamma) s << ", gamma " << FormatNumber(c.after.gamma, 4);
    s << ", rms " << FormatNumber(c.rms_dn, 3) << " DN over " << c.residuals << " shot channels";
    if (c.temperatures_k.size() >= 2) {
      s << ", spectral check "
        << FormatNumber(100 * c.spectral_mismatch.head(c.channels).maxCoeff(), 3) << "%";
    }
    s << "\n";
    for (const std::string& w : c.warnings) s << "  WARNING: " << w << "\n";
  }
  return s.str();
}

std::string RadiometricCalibration::Report() const {
  std::ostringstream s;
  s << "# Radiometric calibration\n\n"
    << "Each camera's gains, black level (and gamma) fitted to its images of a "
    << (lamp ? "lamp (the gains' ratios only)" : "black body")
    << " at several exposures (pipeline/radiometric_calibration.h).\n\n"
    << (exposure_unit_us > 0 && !lamp
            ? "Exposure 1 stands for " + FormatNumber(exposure_unit_us) +
                  " us at 0 dB (the shots' exposure_unit_us), and the rig keeps it: `flamerig "
                  "run` knows a recording's exposure from its first camera's settings.\n\n"
        : exposure_unit_us > 0
            ? "The shots' exposure_unit_us is not kept: a lamp fixes the gains' ratios, not "
              "their scale, so a recording's exposure is not known from its settings.\n\n"
            : std::string())
    << "| camera | spectral | gain before | gain after | black before | black after | gamma | rms "
       "(DN) | shot channels | dark pixels (DN) | spectral check |\n"
    << "|---|---|---|---|---|---|---|---|---|---|---|\n";
  auto gains = [](const CameraRadiometry& r, int channels) {
    std::string g;
    for (int i = 0; i < channels; ++i) g += (i ? " / " : "") + FormatNumber(r.gain[i], 4);
    return g;
  };
  for (const CameraRadiometricResult& c : cameras) {
    s << "| " << c.camera << " | " << c.before.spectral.Describe() << " | "
      << gains(c.before, c.channels) << " | " << gains(c.after, c.channels) << " | "
      << FormatNumber(c.before.black_level, 4) << " | " << FormatNumber(c.after.black_level, 4)
      << (c.fitted_black_level      ? ""
          : c.black_level_from_dark ? " (dark pixels)"
                                    : " (held)")
      << " | "
      << (c.after.transfer == TransferFunction::kGamma
              ? FormatNumber(c.after.gamma, 4) + (c.fitted_gamma ? "" : " (held)")
              : std::string(ToString(c.after.transfer)))
      << " | " << FormatNumber(c.rms_dn, 3) << " | " << c.residuals << " | "
      << FormatNumber(c.dark_level_dn, 4) << " | ";
    if (c.temperatures_k.size() >= 2) {
      for (int i = 0; i < c.channels; ++i)
        s << (i ? " / " : "") << FormatNumber(100 * c.spectral_mismatch[i], 3) << "%";
    } else {
      s << "one temperature";
    }
    s << " |\n";
  }
  for (const CameraRadiometricResult& c : cameras) {
    if (c.notes.empty() && c.warnings.empty()) continue;
    s << "\n**" << c.camera << "** (patch [" << c.region[0] << ", " << c.region[1] << ", "
      << c.region[2] << ", " << c.region[3] << "])\n\n";
    for (const std::string& w : c.warnings) s << "- **Warning:** " << w << "\n";
    for (const std::string& n : c.notes) s << "- " << n << "\n";
  }
  s << "\nThe spectral check: per channel, the largest |measured / model - 1| over the source "
       "temperatures; a right spectral model gives noise only.\n\n## Shots\n\n"
    << "| camera | image | T (K) | exposure | mean code | model code | note |\n"
    << "|---|---|---|---|---|---|---|\n";
  for (const RadiometricShotResult& r : shots) {
    const int channels = [&] {
      for (const CameraRadiometricResult& c : cameras)
        if (c.camera == r.shot.camera) return c.channels;
      return 3;
    }();
    std::string mean, model, left;
    for (int i = 0; i < channels; ++i) {
      mean += (i ? " / " : "") + FormatNumber(r.mean_code[i], 5);
      model += (i ? " / " : "") + (r.model_code[i] != 0 ? FormatNumber(r.model_code[i], 5) : "-");
      if (!r.left_out[i].empty())
        left += (left.empty() ? "" : "; ") + std::string(1, channels == 1 ? 'M' : "RGB"[i]) + ": " +
                r.left_out[i];
    }
    s << "| " << r.shot.camera << " | " << fs::path(r.shot.image).filename().string() << " | "
      << FormatNumber(r.shot.temperature_k, 4) << " | " << FormatNumber(r.shot.exposure, 4) << " | "
      << mean << " | " << model << " | " << left << " |\n";
  }
  return s.str();
}

void RadiometricCalibration::WriteCsv(const std::string& path) const {
  std::ofstream f(path);
  f << "camera,image,temperature_k,exposure,channel,patch_pixels,mean_code,model_code,note\n";
  f.precision(10);
  for (const RadiometricShotResult& r : shots) {
    int channels = 3;
    for (const CameraRadiometricResult& c : cameras)
      if (c.camera == r.shot.camera) channels = c.channels;
    for (int i = 0; i < channels; ++i)
      f << r.shot.camera << "," << fs::path(r.shot.image).filename().string() << ","
        << r.shot.temperature_k << "," << r.shot.exposure << "," << i << "," << r.patch_pixels
        << "," << r.mean_code[i] << "," << r.model_code[i] << ",\"" << r.left_out[i] << "\"\n";
  }
  if (!f) throw IoError("cannot write " + path);
}

RadiometricCalibration RunRadiometricCalibration(const std::string& rig_path,
                                                 const std::string& shots_path,
                                                 const std::string& out_dir,
                                                 const RadiometricOptions& options) {
  // OUT/rig.yaml must not be the rig being calibrated: its datasheet model would be lost.
  {
    std::error_code a, b;
    const fs::path in = fs::weakly_canonical(rig_path, a),
                   written = fs::weakly_canonical(fs::path(out_dir) / "rig.yaml", b);
    if (!a && !b && in == written)
      throw InputError("calibrate-radiometry: --out " + out_dir + " would overwrite the rig " +
                       rig_path + " that it calibrates: give another folder");
  }
  const Rig rig = Rig::Load(rig_path);
  const RadiometricShots shots = RadiometricShots::Load(shots_path);
  RadiometricCalibration calibration = CalibrateRadiometry(rig, shots, options);
  fs::create_directories(out_dir);
  // The rig is written last: a rig.yaml in OUT means a complete calibration.
  const fs::path out(out_dir);
  {
    std::ofstream f(out / "report.md");
    f << calibration.Report();
    if (!f) throw IoError("cannot write " + (out / "report.md").string());
  }
  calibration.WriteCsv((out / "shots.csv").string());
  ApplyRadiometricCalibration(rig, calibration).Save((out / "rig.yaml").string());
  return calibration;
}

int FilmCalibrationSource(int width, int height, double temperature_k, double emissivity,
                          double exposure, const CameraRadiometry& film, double noise_dn,
                          std::uint64_t seed, ImageU8* u8, ImageU16* u16) {
  const Eigen::Vector3d radiance =
      emissivity * ChannelResponse::ForCamera(film)->Blackbody(temperature_k);
  ImageF linear(width, height, 3);
  const double cx = 0.5 * width, cy = 0.5 * height, radius = 0.25 * std::min(width, height);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const double d = std::hypot(x + 0.5 - cx, y + 0.5 - cy);
      const double cover = std::clamp((radius - d) / 3.0 + 0.5, 0.0, 1.0);
      for (int c = 0; c < 3; ++c) linear.at(x, y, c) = float(cover * radiance[c]);
    }
  return RecordCameraImage(linear, exposure, film, noise_dn, seed, u8, u16);
}

}  // namespace flamerig
