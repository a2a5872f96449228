#include "pipeline/reconstruct_job.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>

#include "core/error.h"
#include "fitting/renderer.h"
#include "pipeline/frame_source.h"
#include "pipeline/picture.h"
#include "pipeline/report_page.h"
#include "pipeline/run.h"
#include "pipeline/truth.h"
#include "tomography/vdb_io.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

// One camera's masks over its input brightened 4x (`bright`, so that faint specks show): the
// dilated mask's margin tinted blue, specks magenta, and the hull's outline green.
ImageU8 MaskOverlay(const CameraMaskSummary& m, const ImageU8& bright) {
  ImageU8 out(m.width, m.height, 3);
  auto has = [&](int x, int y, std::uint8_t bit) {
    return x >= 0 && y >= 0 && x < m.width && y < m.height &&
           (m.labels[static_cast<std::size_t>(y) * m.width + x] & bit) != 0;
  };
  for (int y = 0; y < m.height; ++y)
    for (int x = 0; x < m.width; ++x) {
      const std::size_t p = static_cast<std::size_t>(y) * m.width + x;
      const std::uint8_t l = m.labels[p];
      Rgb c = {bright.pixels[3 * p], bright.pixels[3 * p + 1], bright.pixels[3 * p + 2]};
      if (l & kMaskSpeck) {
        c = {255, 0, 255};
      } else if (!(l & kMaskFire) && (l & CameraMaskSummary::kMaskDilated)) {
        c = {static_cast<std::uint8_t>(c[0] / 2), static_cast<std::uint8_t>(c[1] / 2),
             static_cast<std::uint8_t>(std::min(255, c[2] / 2 + 110))};
      }
      const bool hull = l & CameraMaskSummary::kMaskHull;
      if (hull && !(has(x - 1, y, CameraMaskSummary::kMaskHull) &&
                    has(x + 1, y, CameraMaskSummary::kMaskHull) &&
                    has(x, y - 1, CameraMaskSummary::kMaskHull) &&
                    has(x, y + 1, CameraMaskSummary::kMaskHull)))
        c = {0, 230, 0};
      for (int ch = 0; ch < 3; ++ch) out.pixels[3 * p + ch] = c[ch];
    }
  return out;
}

std::string MaskLine(const CameraMaskSummary& m) {
  return fmt::format(
      "{}{}: fire {} px ({:.1f}% of the image once dilated), threshold {:.3g} "
      "(noise {:.3g}, estimated {:.3g}), {} speck(s) of {} px removed (< {} px)",
      m.camera, m.held_out ? " (held out)" : "", m.fire_pixels, 100 * m.fraction, m.threshold,
      m.noise_sigma, m.noise_estimate, m.speck_regions, m.speck_pixels, m.min_speck_px);
}

// DIR/<camera>.png (the dilated mask, white) for every camera, and DIR/masks.png; returns the
// picture. Masks are on the tomography's pixels: binned bin x bin (ReconstructOptions::bin).
ImageU8 WriteMasks(const std::string& dir, const Rig& rig, const SourceFrameSet& set,
                   const std::vector<CameraMaskSummary>& masks, int bin) {
  PictureGrid grid;
  grid.title =
      "Fire masks: blue = the dilated margin, magenta = specks removed, green = the "
      "visual hull's outline";
  grid.column_labels = {"input (x4 brightness)", "masks and hull"};
  for (const CameraMaskSummary& m : masks) {
    if (m.labels.empty()) continue;
    const int c = rig.FindCamera(m.camera);
    const ImageU8& input = c >= 0 ? set.images[c] : ImageU8();
    // The masks are on the tomography's pixels: binned ones (ReconstructOptions::bin) show the
    // input pixel at each block's centre.
    ImageU8 bright(m.width, m.height, 3);
    if (!input.empty() && input.channels == 3) {
      const int k = std::max(1, bin);
      for (int y = 0; y < m.height; ++y)
        for (int x = 0; x < m.width; ++x) {
          const int sx = std::min(input.width - 1, x * k + k / 2),
                    sy = std::min(input.height - 1, y * k + k / 2);
          for (int c = 0; c < 3; ++c)
            bright.pixels[(static_cast<std::size_t>(y) * m.width + x) * 3 + c] =
                static_cast<std::uint8_t>(std::min(
                    255,
                    4 * input.pixels[(static_cast<std::size_t>(sy) * input.width + sx) * 3 + c]));
        }
    }
    grid.row_labels.push_back(m.camera + (m.held_out ? " (held out)" : ""));
    grid.rows.push_back({bright, MaskOverlay(m, bright)});
    if (!dir.empty()) {
      ImageU8 binary(m.width, m.height, 1);
      for (std::size_t p = 0; p < binary.pixels.size(); ++p)
        binary.pixels[p] = (m.labels[p] & CameraMaskSummary::kMaskDilated) ? 255 : 0;
      WritePng((fs::path(dir) / (m.camera + ".png")).string(), binary);
    }
  }
  ImageU8 picture = DrawPictureGrid(grid);
  if (!dir.empty()) WritePng((fs::path(dir) / "masks.png").string(), picture);
  return picture;
}

}  // namespace

ReconstructJobResult RunReconstructJob(const ReconstructJob& job,
                                       const ProgressCallback& progress) {
  if (!job.truth_path.empty() && !fs::is_regular_file(job.truth_path))
    throw InputError(job.truth_path + " (--truth): no such file");
  ReconstructJobResult out;
  ReconstructOptions options = job.reconstruct;
  const Rig rig = WithInputTransfer(Rig::Load(job.rig_path), job.input_transfer);
  ImagesExposure exposure = ResolveExposure(job.exposure, job.rig_path, job.images_dir);
  ExposureFromReference([&] { return ReadExportedReference(job.images_dir); }, rig, job.rig_path,
                        &exposure);
  options.exposure = exposure.value;
  out.exposure_source = exposure.known ? exposure.from : "default 1";
  out.exposure = options.exposure;
  // The emission is in the cameras' own unit-gain channels: linear sRGB only when every camera is
  // the sRGB observer (a truth's emission is linear sRGB, so only then can they be compared).
  std::string channels;
  for (const RigCamera& c : rig.cameras) {
    // The response's kind and name (ChannelResponse::name), without building its tables.
    const SpectralSensitivity& s = c.radiometry.spectral;
    if (s.kind != SpectralSensitivity::Kind::kSrgbObserver &&
        channels.find(s.Describe()) == std::string::npos)
      channels += (channels.empty() ? "" : "; ") + s.Describe();
  }
  options.keep_masks = options.keep_masks || !job.masks_dir.empty() || !job.report_dir.empty();
  options.keep_coarse_matrix = false;  // one frame
  SourceFrameSet set = ReadFrameFolder(rig, job.images_dir, options.exposure);
  out.notes = set.notes;
  for (const auto& [name, what] : {std::pair{options.holdout_camera, "held-out camera"},
                                   std::pair{options.stop_camera, "stop camera"}}) {
    if (name.empty()) continue;
    const int h = rig.FindCamera(name);
    if (h >= 0 && set.images[h].empty())
      throw InputError(std::string(what) + " '" + name + "' has no image in " + job.images_dir +
                       ": nothing to score on");
  }
  set.signal.clear();  // the fit's input, not the tomography's
  set.signal.shrink_to_fit();
  Reconstructor reconstructor(rig, options);
  FireVolume volume = reconstructor.Reconstruct(set.linear, &out.summary, nullptr, progress);
  volume.metadata_text["exposure_source"] = out.exposure_source;
  if (!channels.empty())
    volume.metadata_text["emission_units"] =
        "radiance per metre in the cameras' own unit-gain channels (" + channels +
        "), not linear sRGB";
  if (fs::path(job.out_path).has_parent_path())
    fs::create_directories(fs::path(job.out_path).parent_path());
  WriteVdb(job.out_path, volume);
  ImageU8 views;
  if (!job.preview_path.empty() || !job.report_dir.empty()) {
    // Each camera: its input, the reconstruction rendered back through it, and 4x their difference.
    PictureGrid grid;
    grid.column_labels = {"input", "reconstruction rendered back", "|difference| x 4"};
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      const ImageU8& input = set.images[c];
      if (input.empty()) continue;
      const ImageU8 rendered =
          ApplyCameraResponse(RenderThinEmission(volume.geometry, volume.emission_rgb,
                                                 CameraRays(rig.cameras[c].model)),
                              options.exposure);
      ImageU8 difference(rendered.width, rendered.height, 3);
      for (std::size_t p = 0; p < difference.pixels.size(); ++p)
        difference.pixels[p] = static_cast<std::uint8_t>(
            std::min(255, 4 * std::abs(int(input.pixels[p]) - int(rendered.pixels[p]))));
      grid.row_labels.push_back(rig.cameras[c].name);
      grid.rows.push_back({input, rendered, difference});
    }
    views = DrawPictureGrid(grid);
    if (!job.preview_path.empty()) WritePng(job.preview_path, views);
  }
  if (!job.truth_path.empty() && !channels.empty())
    out.notes.push_back("the volume is not compared with the truth " + job.truth_path +
                        ": its emission is in the cameras' own channels (" + channels +
                        "), the truth's in linear sRGB (fit --truth scores temperatures)");
  else if (!job.truth_path.empty())
    out.truth_error = EmissionError(volume, ReadVdb(job.truth_path), job.truth_path);
  if (!job.masks_dir.empty()) fs::create_directories(job.masks_dir);
  ImageU8 masks;
  if (!job.masks_dir.empty() || !job.report_dir.empty())
    masks = WriteMasks(job.masks_dir, rig, set, out.summary.masks, out.summary.bin);
  if (!job.report_dir.empty()) {
    fs::create_directories(job.report_dir);
    WritePng((fs::path(job.report_dir) / "views.png").string(), views);
    ReportPage page("flamerig reconstruct",
                    {{"rig", job.rig_path}, {"images", job.images_dir}, {"volume", job.out_path}});
    page.Section("Tomography");
    page.Text(out.summary.BriefReport());
    std::vector<std::string> facts = {"Exposure " + std::to_string(out.exposure) + " (" +
                                      HtmlEscape(out.exposure_source) + ")."};
    for (const auto& n : out.notes) facts.push_back(HtmlEscape(n));
    if (out.truth_error >= 0) {
      facts.push_back(fmt::format(
          "Relative L2 error of the emission against the truth (<code>{}</code>): <b>{:.4f}</b>.",
          HtmlEscape(job.truth_path), out.truth_error));
    }
    page.List(facts);
    page.Section("Fire masks");
    std::vector<std::string> lines;
    for (const auto& m : out.summary.masks) lines.push_back(HtmlEscape(MaskLine(m)));
    page.List(lines);
    WritePng((fs::path(job.report_dir) / "masks.png").string(), masks);
    page.Figure("masks.png",
                "Each camera's input brightened 4x, and its masks: the dilated margin blue, specks "
                "removed magenta, the outline of the visual hull green.");
    page.Section("Views");
    page.Figure("views.png",
                "Each camera: its input, the reconstructed emission rendered back through it (thin "
                "limit), and their absolute difference times 4.");
    page.Write((fs::path(job.report_dir) / "index.html").string());
  }
  return out;
}

}  // namespace flamerig
