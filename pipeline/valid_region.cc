#include "pipeline/valid_region.h"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <sstream>

#include "calibration/camera_model.h"
#include "calibration/mrcal_inputs.h"
#include "core/error.h"
#include "core/format.h"
#include "core/read_file.h"
#include "pipeline/subprocess.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

// Run as `python3 -c SCRIPT uncertainty mean stdev count distance grid_width MODEL...`: for each
// model, MODEL.region holds "uncertainty MIN MEDIAN SIGMA" (the projection uncertainty over the
// grid's cell centres and the residuals' deviation, px) and then the contour's points ("x y" per
// line, none for an empty region), or one line "error: ...". The thresholds are scaled as
// mrcal-calibrate-cameras scales them, by the standard deviation of the solve's board residuals.
constexpr const char* kScript = R"(
import sys
try:
    import numpy as np
    import mrcal
    from mrcal.calibration import _compute_valid_intrinsics_region
except Exception as e:
    sys.stderr.write("mrcal's Python package cannot be imported: %s\n" % e)
    sys.exit(3)
u, mean, stdev, count, distance, gridn = [float(x) for x in sys.argv[1:7]]
# The region's own grid of projection uncertainties, kept as mrcal computes it (a copy: mrcal then
# marks the non-finite cells 1e9 in place) so that the figures below need no second computation.
seen = []
computed = mrcal.projection_uncertainty
def kept(*args, **kwargs):
    result = computed(*args, **kwargs)
    seen.append(np.array(result, copy=True))
    return result
mrcal.projection_uncertainty = kept
for path in sys.argv[7:]:
    with open(path + ".region", "w") as out:
        try:
            m = mrcal.cameramodel(path)
            oi = m.optimization_inputs()
            if oi is None:
                raise Exception("the model carries no optimization_inputs")
            sigma = np.std(mrcal.residuals_chessboard(oi).ravel())
            seen.clear()
            r = _compute_valid_intrinsics_region(m, u * sigma, mean, stdev * sigma, count,
                                                 distance, gridn_width=int(gridn))
            if len(seen) != 1:
                raise Exception("mrcal computed the projection uncertainty %d times, not once"
                                % len(seen))
            unc = seen[0][np.isfinite(seen[0])]
            out.write("uncertainty %.9g %.9g %.9g\n" % (
                np.min(unc) if unc.size else float("inf"),
                np.median(unc) if unc.size else float("inf"), sigma))
            for x, y in r:
                out.write("%d %d\n" % (x, y))
        except Exception as e:
            out.write("error: %s\n" % str(e).replace("\n", " "))
)";

double ContourArea(const std::vector<Eigen::Vector2i>& c) {
  double twice = 0;
  for (std::size_t i = 0; i + 1 < c.size(); ++i)
    twice += double(c[i].x()) * c[i + 1].y() - double(c[i + 1].x()) * c[i].y();
  return std::abs(twice) / 2;
}

// Three numbers after the sidecar's "uncertainty " (strtod reads the "inf" that Python writes
// when no cell's uncertainty is finite, which a stream's >> does not).
bool ParseUncertaintyLine(const std::string& rest, ValidRegion* r) {
  double v[3];
  const char* p = rest.c_str();
  for (double& x : v) {
    char* end = nullptr;
    x = std::strtod(p, &end);
    if (end == p) return false;
    p = end;
  }
  r->min_uncertainty_px = v[0];
  r->median_uncertainty_px = v[1];
  r->residual_sigma_px = v[2];
  return true;
}

}  // namespace

ValidRegionParameters ValidRegionParameters::FromMrcal(const std::vector<double>& five,
                                                       const std::string& where) {
  if (five.size() != 5)
    throw InputError(where +
                     ": needs mrcal's five numbers (uncertainty, mean, stdev, count, "
                     "distance; its defaults 1 0.5 1.5 3 0), not " +
                     std::to_string(five.size()));
  for (double x : five)
    if (!std::isfinite(x)) throw InputError(where + ": " + FormatNumber(x) + " is not finite");
  ValidRegionParameters p;
  p.uncertainty = five[0];
  p.mean = five[1];
  p.stdev = five[2];
  p.distance_m = five[4];
  if (p.uncertainty <= 0 || p.mean <= 0 || p.stdev <= 0)
    throw InputError(where + ": the thresholds (the first three numbers) must be above zero");
  if (five[3] < 0 || five[3] != std::floor(five[3]) || five[3] > 1e6)
    throw InputError(where + ": the count (the fourth number) must be a whole number >= 0, not " +
                     FormatNumber(five[3]));
  p.count = static_cast<int>(five[3]);
  if (p.distance_m < 0)
    throw InputError(where +
                     ": the distance (the fifth number) must be 0 (infinity) or above, "
                     "in metres, not " +
                     FormatNumber(p.distance_m));
  return p;
}

std::string ValidRegionParameters::ToMrcal() const {
  return FormatNumber(uncertainty) + " " + FormatNumber(mean) + " " + FormatNumber(stdev) + " " +
         std::to_string(count) + " " + FormatNumber(distance_m);
}

std::string ValidRegionParameters::DistanceText() const {
  return distance_m > 0 ? "at " + FormatNumber(distance_m) + " m" : std::string("at infinity");
}

std::vector<ValidRegion> AddValidIntrinsicsRegions(const std::vector<std::string>& model_paths,
                                                   const ValidRegionParameters& p) {
  std::vector<ValidRegion> regions(model_paths.size());
  for (std::size_t i = 0; i < model_paths.size(); ++i) regions[i].model_path = model_paths[i];
  if (model_paths.empty()) return regions;
  // mrcal's own tools run /usr/bin/python3 (their #! line): the interpreter Debian's
  // python3-mrcal is installed for, whatever python3 comes first in PATH.
  std::vector<std::string> argv = {"/usr/bin/python3",
                                   "-c",
                                   kScript,
                                   FormatNumber(p.uncertainty, 17),
                                   FormatNumber(p.mean, 17),
                                   FormatNumber(p.stdev, 17),
                                   std::to_string(p.count),
                                   FormatNumber(p.distance_m, 17),
                                   std::to_string(p.grid_width)};
  for (const std::string& path : model_paths) {
    fs::remove(path + ".region");
    argv.push_back(fs::absolute(path).string());
  }
  const ProgramResult run = RunProgram(argv);
  std::string failed;
  if (!run.started)
    failed = "/usr/bin/python3 could not be run (" + run.error + ")";
  else if (run.exit_status != 0) {
    std::string why = run.error;
    while (!why.empty() && (why.back() == '\n' || why.back() == '\r')) why.pop_back();
    failed = "/usr/bin/python3 with mrcal failed (status " + std::to_string(run.exit_status) +
             (why.empty() ? std::string() : ": " + why) + ")";
  }
  for (ValidRegion& r : regions) {
    const std::string sidecar = fs::absolute(r.model_path).string() + ".region";
    if (!failed.empty() || !fs::exists(sidecar)) {
      r.error = failed.empty() ? "mrcal wrote no region" : failed;
      std::error_code ignored;
      fs::remove(sidecar, ignored);
      continue;
    }
    std::istringstream lines(ReadFile(sidecar));
    fs::remove(sidecar);
    std::string line;
    bool ok = true;
    while (std::getline(lines, line)) {
      if (line.rfind("error: ", 0) == 0) {
        r.error = "mrcal: " + line.substr(7);
        ok = false;
        break;
      }
      if (line.rfind("uncertainty ", 0) == 0) {
        if (!ParseUncertaintyLine(line.substr(12), &r)) {
          r.error = "mrcal's uncertainty line is unreadable: '" + line + "'";
          ok = false;
          break;
        }
        continue;
      }
      std::istringstream xy(line);
      int x = 0, y = 0;
      if (!(xy >> x >> y)) {
        r.error = "mrcal's region is unreadable: '" + line + "'";
        ok = false;
        break;
      }
      r.contour.emplace_back(x, y);
    }
    if (!ok) {
      r.contour.clear();
      continue;
    }
    std::ostringstream field;
    field << "    # Where the calibration can be trusted, as mrcal-calibrate-cameras computes it "
             "(its function,\n    # --valid-intrinsics-region-parameters "
          << p.ToMrcal() << "): a closed contour in pixels.\n"
          << "    'valid_intrinsics_region': [\n";
    for (const Eigen::Vector2i& q : r.contour)
      field << "    [ " << q.x() << ", " << q.y() << " ],\n";
    field << "    ],\n";
    try {
      const CameraModel model = CameraModel::Load(r.model_path);
      AddCameraModelFields(r.model_path, field.str());
      r.imager_fraction = ContourArea(r.contour) / (double(model.width()) * model.height());
    } catch (const Error& e) {
      r.error = e.what();
      r.contour.clear();
      continue;
    }
    r.computed = true;
  }
  return regions;
}

std::vector<Eigen::Vector2i> ReadValidIntrinsicsRegion(const std::string& model_path) {
  const std::string text = ReadFile(model_path);
  const std::size_t key = text.find("'valid_intrinsics_region'");
  if (key == std::string::npos) return {};
  const std::size_t open = text.find('[', key);
  if (open == std::string::npos)
    throw DataError(model_path + ": 'valid_intrinsics_region' is not a list");
  std::vector<Eigen::Vector2i> contour;
  int depth = 0;
  std::size_t i = open;
  for (; i < text.size(); ++i) {
    if (text[i] == '[') {
      if (++depth == 2) {
        const std::size_t close = text.find(']', i);
        if (close == std::string::npos) break;
        std::string pair = text.substr(i + 1, close - i - 1);
        for (char& ch : pair)
          if (ch == ',') ch = ' ';
        std::istringstream in(pair);
        double x = 0, y = 0;
        if (!(in >> x >> y))
          throw DataError(model_path + ": a point of 'valid_intrinsics_region' is not [x, y]: [" +
                          text.substr(i + 1, close - i - 1) + "]");
        contour.emplace_back(static_cast<int>(std::lround(x)), static_cast<int>(std::lround(y)));
        i = close;
        --depth;
      }
    } else if (text[i] == ']') {
      if (--depth == 0) break;
    }
  }
  if (depth != 0) throw DataError(model_path + ": 'valid_intrinsics_region' is not closed");
  return contour;
}

}  // namespace flamerig
