#include "pipeline/tomography_config.h"

#include <filesystem>

#include "calibration/radiometry.h"
#include "core/config_reader.h"
#include "core/error.h"

namespace flamerig {

void LoadTomographyConfig(const std::string& path, ReconstructOptions* options,
                          std::string* input_transfer) {
  const YAML::Node root = LoadYamlFile(path, "tomography config");
  if (!root.IsMap() || !root["tomography"] || !root["tomography"].IsMap())
    throw InputError(path + ": a tomography config is a map with a 'tomography:' map");
  ConfigReader top(root, path);
  top.Seen("tomography");
  top.CheckKnown();
  const YAML::Node node = root["tomography"];
  ConfigReader r(node, path + ": tomography");
  ReconstructOptions& o = *options;
  o.resolution = r.Whole<int>("resolution", o.resolution, 1, 1024);
  o.bin = r.Whole<int>("bin", o.bin, 1, 16);
  const std::string transfer = r.Get<std::string>("input_transfer", *input_transfer);
  if (!transfer.empty()) {
    TransferFunction t;
    double gamma;
    try {
      ParseTransferSpec(transfer, &t, &gamma);
    } catch (const InputError& e) {
      throw InputError(r.where() + ": 'input_transfer': " + e.what());
    }
  }
  *input_transfer = transfer;
  o.solve.solver = r.Get<std::string>("solver", o.solve.solver);
  o.solve.max_iterations = r.Whole<int>("max_iterations", o.solve.max_iterations, 1, 100000);
  o.solve.relaxation = r.Range("relaxation", o.solve.relaxation, 1e-3, 1.999);
  o.solve.stagnation_tolerance =
      r.Range("stagnation_tolerance", o.solve.stagnation_tolerance, -1, 1);
  if (o.solve.stagnation_tolerance < 0 && o.solve.stagnation_tolerance != -1)
    throw InputError(r.where() + ": 'stagnation_tolerance' is -1 (the solver's own) or in [0, 1]");
  o.warm_stagnation_tolerance =
      r.Range("warm_stagnation_tolerance", o.warm_stagnation_tolerance, -1, 1);
  if (o.warm_stagnation_tolerance < 0 && o.warm_stagnation_tolerance != -1)
    throw InputError(r.where() +
                     ": 'warm_stagnation_tolerance' is -1 (as a cold solve) or in [0, 1]");
  o.two_view_fine_iterations =
      r.Whole<int>("two_view_fine_iterations", o.two_view_fine_iterations, -1, 100000);
  if (o.two_view_fine_iterations < 1 && o.two_view_fine_iterations != -1)
    throw InputError(r.where() +
                     ": 'two_view_fine_iterations' is -1 (the solve's own rules) or >= 1");
  o.solve.holdout_patience = r.Whole<int>("holdout_patience", o.solve.holdout_patience, 1, 100000);
  o.solve.prior = r.Get<std::string>("prior", o.solve.prior);
  o.solve.prior_weight = r.Range("prior_weight", o.solve.prior_weight, -1, 10);
  if (o.solve.prior_weight < 0 && o.solve.prior_weight != -1)
    throw InputError(r.where() + ": 'prior_weight' is -1 (the prior's own) or in [0, 10]");
  o.solve.prior_edge = r.Range("prior_edge", o.solve.prior_edge, 1e-6, 1e6);
  o.coarse_to_fine = r.Get<bool>("coarse_to_fine", o.coarse_to_fine);
  o.coarse_iterations = r.Whole<int>("coarse_iterations", o.coarse_iterations, 1, 100000);
  o.envelope_margin_voxels =
      r.Whole<int>("envelope_margin_voxels", o.envelope_margin_voxels, 0, 16);
  const std::string cache = r.Get<std::string>("cache", "");
  if (!cache.empty())
    o.cache_dir = (std::filesystem::path(path).parent_path() / cache).lexically_normal().string();
  if (const YAML::Node mask = node["mask"]) {
    r.Seen("mask");
    if (!mask.IsMap()) throw InputError(r.where() + ": 'mask' must be a map");
    ConfigReader m(mask, r.where() + ".mask");
    VisualHullOptions& h = o.hull;
    h.threshold_sigmas = m.Range("threshold_sigmas", h.threshold_sigmas, 1e-3, 1e6);
    h.noise_sigma = m.NonNegative("noise", h.noise_sigma);
    h.dilation_px = m.Whole<int>("dilation_px", h.dilation_px, 0, 64);
    h.min_views = m.Whole<int>("min_views", h.min_views, 1, 1000);
    h.min_speck_px = m.Whole<int>("min_speck_px", h.min_speck_px, -1, 1000000);
    m.CheckKnown();
  }
  r.CheckKnown();
  try {
    ReconstructOptions check = o;
    check.exposure = 1;
    check.Validate();
  } catch (const InputError& e) {
    throw InputError(path + ": " + e.what());
  }
}

}  // namespace flamerig
