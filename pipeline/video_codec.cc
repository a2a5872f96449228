#include "pipeline/video_codec.h"

#include <unistd.h>

#include <atomic>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "core/error.h"
#include "pipeline/subprocess.h"

namespace flamerig {

namespace fs = std::filesystem;

void VideoCodecOptions::Validate() const {
  auto plain = [](const std::string& s) {
    if (s.empty()) return false;
    for (char c : s)
      if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-')) return false;
    return true;
  };
  if (!plain(codec)) throw InputError("video codec: 'codec' must name an ffmpeg encoder");
  if (crf < 0 || crf > 63) throw InputError("video codec: 'crf' must be in [0, 63]");
  if (!plain(preset)) throw InputError("video codec: 'preset' must name a preset");
  if (!plain(pixel_format)) throw InputError("video codec: 'pixel_format' must name one");
}

std::string VideoCodecOptions::Describe() const {
  return codec + " crf " + std::to_string(crf) + " (" + preset + ", " + pixel_format + ")";
}

namespace {

// A folder of its own under the system's temporary folder, removed when it goes.
class TempDir {
 public:
  TempDir() {
    static std::atomic<int> counter{0};
    path_ = fs::temp_directory_path() /
            ("flamerig-codec-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ignored;
    fs::remove_all(path_, ignored);
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

void Run(const std::vector<std::string>& argv, const std::string& what) {
  const ProgramResult r = RunProgram(argv);
  if (!r.started) throw IoError(r.error + ": install ffmpeg (scripts/install-deps.sh)");
  if (!r.ok())
    throw IoError("ffmpeg failed " + what + " (exit " + std::to_string(r.exit_status) +
                  "): " + r.error.substr(0, 500));
}

}  // namespace

std::vector<ImageU8> ThroughVideoCodec(const std::vector<ImageU8>& frames,
                                       const VideoCodecOptions& options) {
  options.Validate();
  if (frames.empty()) return {};
  const int width = frames[0].width, height = frames[0].height;
  for (std::size_t i = 0; i < frames.size(); ++i)
    if (frames[i].width != width || frames[i].height != height || frames[i].channels != 3)
      throw InputError("video codec: frame " + std::to_string(i) + " is " +
                       std::to_string(frames[i].width) + "x" + std::to_string(frames[i].height) +
                       "x" + std::to_string(frames[i].channels) + ", frame 0 " +
                       std::to_string(width) + "x" + std::to_string(height) +
                       "x3: give RGB frames of one size");
  if (width <= 0 || height <= 0) throw InputError("video codec: empty frames");
  // 4:2:0 and 4:2:2 need even sizes: pad by a repeated edge, crop back after.
  const int pw = width + (width & 1), ph = height + (height & 1);
  TempDir temp;
  const fs::path raw_in = temp.path() / "in.rgb", video = temp.path() / "video.mkv",
                 raw_out = temp.path() / "out.rgb";
  {
    std::ofstream out(raw_in, std::ios::binary);
    std::vector<std::uint8_t> row(static_cast<std::size_t>(pw) * 3);
    for (const ImageU8& f : frames)
      for (int y = 0; y < ph; ++y) {
        const int sy = std::min(y, height - 1);
        for (int x = 0; x < pw; ++x)
          for (int c = 0; c < 3; ++c) row[3 * x + c] = f.at(std::min(x, width - 1), sy, c);
        out.write(reinterpret_cast<const char*>(row.data()),
                  static_cast<std::streamsize>(row.size()));
      }
    if (!out) throw IoError(raw_in.string() + ": cannot write the frames for ffmpeg");
  }
  const std::string size = std::to_string(pw) + "x" + std::to_string(ph);
  Run({"ffmpeg",
       "-nostdin",
       "-loglevel",
       "error",
       "-y",
       "-f",
       "rawvideo",
       "-pix_fmt",
       "rgb24",
       "-s",
       size,
       "-r",
       "30",
       "-i",
       raw_in.string(),
       "-c:v",
       options.codec,
       "-crf",
       std::to_string(options.crf),
       "-preset",
       options.preset,
       "-pix_fmt",
       options.pixel_format,
       video.string()},
      "encoding with " + options.Describe());
  Run({"ffmpeg", "-nostdin", "-loglevel", "error", "-y", "-i", video.string(), "-f", "rawvideo",
       "-pix_fmt", "rgb24", raw_out.string()},
      "decoding");
  std::ifstream in(raw_out, std::ios::binary);
  const std::vector<char> bytes((std::istreambuf_iterator<char>(in)),
                                std::istreambuf_iterator<char>());
  const std::size_t frame_bytes = static_cast<std::size_t>(pw) * ph * 3;
  if (bytes.size() != frame_bytes * frames.size())
    throw IoError("ffmpeg decoded " + std::to_string(bytes.size() / frame_bytes) + " frames of " +
                  size + ", " + std::to_string(frames.size()) + " were encoded");
  std::vector<ImageU8> out(frames.size(), ImageU8(width, height, 3));
  for (std::size_t i = 0; i < frames.size(); ++i)
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x)
        for (int c = 0; c < 3; ++c)
          out[i].at(x, y, c) = static_cast<std::uint8_t>(
              bytes[i * frame_bytes + (static_cast<std::size_t>(y) * pw + x) * 3 + c]);
  return out;
}

}  // namespace flamerig
