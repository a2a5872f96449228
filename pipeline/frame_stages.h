// The stages of `flamerig run`'s per-frame work (pipeline/run.h), one method each, so that a
// caller can run, test and replace them one by one: a test makes a stage fail, counts calls or
// cancels inside one; another pipeline overrides the fit and keeps the rest.
//
// A FrameWork carries one frame from stage to stage; the FrameStages object carries what passes
// from frame to frame (the warm start, the last computed frame's images and tomography, the
// reconstructor and its cached matrices, the chain state written at every commit).
//
// RunFrames calls, per frame i:
//   Read(i) -> SkipUnchanged ? Reuse : (Reconstruct -> Fit -> Write) -> Score -> Commit
// and, when a stage throws a DataError, Fail(what) -> Commit. A stage that is cancelled (through
// the progress callback given to it) throws Cancelled, and RunFrames stops without committing.
// A frame set whose images hold no fire (filmed before ignition or after the flame is out) is not
// a failure: Fit gives it the empty result (fitting/fit.h, NoFireResult), Write writes it like any
// other (so that the take's volumes and its Blender sequence have no gap) with the status "no
// fire", and the next frame starts cold (its tomography too: a black volume is no start).
//
// Errors: DataError for the frame's data (see run.h), InputError and IoError for the run.
// Thread safety: one thread; the stages use TBB inside.
#ifndef FLAMERIG_PIPELINE_FRAME_STAGES_H_
#define FLAMERIG_PIPELINE_FRAME_STAGES_H_

#include <chrono>
#include <cstddef>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "core/progress.h"
#include "fitting/fit.h"
#include "pipeline/band_tomography.h"
#include "pipeline/frame_source.h"
#include "pipeline/run.h"
#include "tomography/reconstruct.h"

namespace flamerig {

// One frame on its way through the stages.
struct FrameWork {
  std::size_t index = 0;
  SourceFrameSet set;
  FrameSummary summary;
  bool unchanged = false;  // SkipUnchanged said so: Reuse replaced Reconstruct..Write
  FireVolume tomography;   // Reconstruct's result
  std::vector<BandTomography>
      bands;                   // a mono rig in several bands: one per band (band_tomography.h)
  FitResult result;            // Fit's result (its volume is what Write writes)
  std::vector<FitView> views;  // the fitted views
  std::vector<FitView> held;   // the held-out view, if any
  bool have_output = false;    // a volume was written (computed or reused)
  // Reconstruct's fire pixels per camera of the solve (its masks': above the threshold, specks
  // removed), and Fit's verdict that the images hold no fire (FrameStages::Fit).
  std::vector<std::pair<std::string, std::size_t>> fire_pixels;
  bool no_fire = false;
  std::chrono::steady_clock::time_point start;
};

// The output files of a run (OUT = options.out_dir).
struct RunPaths {
  std::string out;
  std::string Volume(std::size_t i) const;      // OUT/frame_NNNNNN.vdb
  std::string Summary(std::size_t i) const;     // OUT/frames/frame_NNNNNN.yaml
  std::string Picture(std::size_t i) const;     // OUT/frames/frame_NNNNNN.png
  std::string Profile(std::size_t i) const;     // OUT/frames/frame_NNNNNN_profile.csv (below)
  std::string Tomography(std::size_t i) const;  // OUT/tomography/frame_NNNNNN.vdb
  std::string Blender(std::size_t i) const;     // OUT/blender/frame_NNNNNN.vdb
  std::string StateYaml(std::size_t i) const;   // OUT/state/frame_NNNNNN.yaml
  std::string StateBin(std::size_t i) const;    // OUT/state/frame_NNNNNN.state
  // The summary exists, and so does a non-empty volume unless the summary records a failed frame
  // (a volume deleted after the run makes its frame, and those after it, computed again).
  bool Complete(std::size_t i) const;
  // Profile: an axisymmetric fit's radial profile (fit_report.h's WriteRingProfileCsv, without
  // the truth); no such file for an untied frame.
};

class FrameStages {
 public:
  // Opens the source, the reconstructor (its matrix cache in OUT/cache unless the options name
  // one) and the camera rays; creates OUT's folders. `begin` is the first frame of this call's
  // range: the chain state of the frame before it is not removed.
  FrameStages(const RunOptions& options, const std::string& rig_path, std::size_t begin);
  virtual ~FrameStages();
  FrameStages(const FrameStages&) = delete;
  FrameStages& operator=(const FrameStages&) = delete;

  // Restores what the frame `next` starts from, saved by the commit of frame next - 1.
  virtual void Resume(std::size_t next);

  virtual void Read(FrameWork* w);
  virtual bool SkipUnchanged(FrameWork* w);
  virtual void Reuse(FrameWork* w);
  virtual void Reconstruct(FrameWork* w, const ProgressCallback& progress);
  // FastFit finds no active voxel (NoActiveVoxelsError): the images hold no fire when fewer
  // cameras than the visual hull's min_views see fire pixels (w->no_fire, the empty result); when
  // enough of them do, their views do not meet inside the box, which is a DataError naming them
  // (a wrong rig or box).
  virtual void Fit(FrameWork* w, const ProgressCallback& progress);
  virtual void Write(FrameWork* w);
  virtual void Score(FrameWork* w);
  // A stage threw a DataError: the frame failed, and the next one starts cold.
  virtual void Fail(FrameWork* w, const std::string& what);
  // The chain state, then the summary (the mark of a complete frame); removes the previous frame's
  // chain state.
  virtual void Commit(FrameWork* w);

  const FrameSource& source() const { return source_; }
  const Rig& rig() const { return rig_; }
  const RunPaths& paths() const { return paths_; }
  double exposure() const { return exposure_; }

 protected:
  // What the next frame starts from, saved at every commit (state/frame_NNNNNN.yaml).
  struct Chain {
    long long previous_result = -1;  // frame whose .vdb warm-starts the fit; -1 = cold
    long long last_computed = -1;    // frame whose tomography and images were computed last
  };

  RunOptions options_;
  std::size_t begin_;
  Rig rig_;
  FrameSource source_;
  RunPaths paths_;
  double exposure_ = 1;  // the images', or 1 when unknown
  bool exposure_known_ = false;
  // The take's exposure when the images' is unknown: fitted on the first computed frame, held
  // after it; 0 until then (and under --fit-exposure).
  double take_exposure_ = 0;
  long long take_exposure_frame_ = -1;
  AbsorptionModel absorption_;
  // The options that change a fitted frame, as text, kept in every state file: a run into an OUT
  // whose frames were fitted with other options is refused (it would take them as done).
  std::string fit_key_;
  int holdout_ = -1;
  std::size_t truth_count_ = 0;
  Rigid3 fit_from_truth_;  // RunOptions::truth_rig's frame into the run's
  // Whether a frame starts from the ones before it (the last computed tomography, the last
  // result), as RunOptions::warm_start says.
  bool WarmStart() const;
  // Rig camera c's response for set `set`: its own at the frame's exposure (SourceFrameSet::
  // exposure_ratio, ChannelResponse::Exposed), so that a camera started at other settings than
  // the recording's first, or re-exposed while recording, is fitted as it recorded.
  std::shared_ptr<const ChannelResponse> ResponseOf(const SourceFrameSet& set, std::size_t c) const;
  std::unique_ptr<Reconstructor> reconstructor_;
  std::unique_ptr<BandReconstructor> band_reconstructor_;  // null unless the rig has bands
  std::vector<std::unique_ptr<CameraRays>> rays_;
  std::vector<std::shared_ptr<const ChannelResponse>> responses_;  // per rig camera
  Chain chain_;
  FitResult previous_;
  FireVolume last_tomography_;
  std::vector<ImageU8> last_images_;
  FireVolume scored_;  // what Score compares with the truth (the computed or reused volume)
};

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_FRAME_STAGES_H_
