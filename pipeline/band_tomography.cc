#include "pipeline/band_tomography.h"

#include <stdexcept>

#include "core/error.h"

namespace flamerig {

Responses ResponsesOf(const std::vector<FitView>& views) {
  Responses out;
  for (const FitView& v : views) out.push_back(v.response);
  return out;
}

std::vector<std::vector<std::size_t>> GroupByBand(const Responses& responses) {
  std::vector<std::string> names;
  std::vector<std::vector<std::size_t>> groups;
  bool colour = false;
  for (std::size_t v = 0; v < responses.size(); ++v) {
    const auto& r = responses[v];
    if (!r || r->channels() != 1) {
      colour = true;
      continue;
    }
    std::size_t g = 0;
    while (g < names.size() && names[g] != r->name()) ++g;
    if (g == names.size()) {
      names.push_back(r->name());
      groups.emplace_back();
    }
    groups[g].push_back(v);
  }
  // With colour cameras among them the fit starts from the colour cameras' tomography, as it did
  // before bands: the two starts would disagree.
  if (groups.size() < 2 || colour) return {};
  return groups;
}

BandReconstructor::BandReconstructor(const Rig& rig, ReconstructOptions options)
    : rig_(rig), options_(std::move(options)) {
  options_.holdout_camera.clear();
  options_.stop_camera.clear();
}

std::vector<BandTomography> BandReconstructor::Reconstruct(const Responses& responses,
                                                           const std::vector<int>& rig_index,
                                                           const std::vector<LinearFrame>& frames,
                                                           std::string* report,
                                                           const ProgressCallback& progress) {
  if (rig_index.size() != responses.size())
    throw std::logic_error("BandReconstructor: one rig index per camera");
  std::vector<BandTomography> out;
  for (const auto& group : GroupByBand(responses)) {
    const auto& response = responses[group.front()];
    std::vector<LinearFrame> used(frames.size());
    for (std::size_t v : group)
      used.at(static_cast<std::size_t>(rig_index[v])) =
          frames.at(static_cast<std::size_t>(rig_index[v]));
    std::size_t r = 0;
    while (r < reconstructors_.size() && reconstructors_[r].first != response->name()) ++r;
    if (r == reconstructors_.size())
      reconstructors_.emplace_back(response->name(),
                                   std::make_unique<Reconstructor>(rig_, options_));
    ReconstructSummary summary;
    BandTomography band;
    band.response = response;
    band.tomography = reconstructors_[r].second->Reconstruct(used, &summary, nullptr, progress);
    if (report)
      *report += "band " + response->name() + " from " + std::to_string(group.size()) +
                 " view(s): " + summary.BriefReport() + "\n";
    out.push_back(std::move(band));
  }
  return out;
}

}  // namespace flamerig
