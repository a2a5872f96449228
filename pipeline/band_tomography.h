// Two-colour pyrometry's tomographies (fitting/fit.h, BandTomography; issue 19, item 6): a rig of
// mono cameras behind different band-pass filters has one tomography per band, each solved from
// that band's cameras alone, so that the fit starts each voxel's temperature from the ratio of its
// emission in the bands. The jobs that fit (`fit`, also beside a tomography from a file, and
// `run`) call this; a colour rig, a mono rig in one band, or a rig with colour cameras among its
// fitted ones has no bands.
#ifndef FLAMERIG_PIPELINE_BAND_TOMOGRAPHY_H_
#define FLAMERIG_PIPELINE_BAND_TOMOGRAPHY_H_

#include <memory>
#include <string>
#include <vector>

#include "core/progress.h"
#include "fitting/fit.h"
#include "tomography/reconstruct.h"

namespace flamerig {

// The fitted cameras grouped by band, given each one's response: mono cameras whose spectral
// responses differ (by ChannelResponse::name(): the sensitivity and filter, not the gains) form
// one group per response, of indices into `responses`, in the order they first appear. Empty
// unless there are two groups or more and every camera is mono: with a colour camera (or one
// without a response) among them the fit starts from the colour, as for any colour rig.
using Responses = std::vector<std::shared_ptr<const ChannelResponse>>;
std::vector<std::vector<std::size_t>> GroupByBand(const Responses& responses);
// The same for fitted views (their responses).
Responses ResponsesOf(const std::vector<FitView>& views);

// Per band, a tomography from that band's cameras only (`frames` in rig order; `rig_index` and
// `responses` per fitted camera), with `options` (its held-out and stop cameras dropped: they
// belong to the joint solve). Empty when GroupByBand is. `report` (optional) gets one line per
// band.
class BandReconstructor {
 public:
  BandReconstructor(const Rig& rig, ReconstructOptions options);
  std::vector<BandTomography> Reconstruct(const Responses& responses,
                                          const std::vector<int>& rig_index,
                                          const std::vector<LinearFrame>& frames,
                                          std::string* report = nullptr,
                                          const ProgressCallback& progress = nullptr);

 private:
  Rig rig_;
  ReconstructOptions options_;
  // One per band, kept across frames (each reuses its matrix), keyed by the band's response name.
  std::vector<std::pair<std::string, std::unique_ptr<Reconstructor>>> reconstructors_;
};

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_BAND_TOMOGRAPHY_H_
