#include "acquisition/image.h"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace flamerig {

void WritePng(const std::string& path, const ImageU8& image) {
  if (image.channels != 1 && image.channels != 3) {
    throw std::runtime_error(path + ": cannot write an image with " +
                             std::to_string(image.channels) + " channels (need 1 or 3)");
  }
  cv::Mat view(image.height, image.width, image.channels == 1 ? CV_8UC1 : CV_8UC3,
               const_cast<std::uint8_t*>(image.pixels.data()));
  cv::Mat out;
  if (image.channels == 3) {
    cv::cvtColor(view, out, cv::COLOR_RGB2BGR);
  } else {
    out = view;
  }
  bool ok = false;
  try {
    ok = cv::imwrite(path, out);
  } catch (const cv::Exception& e) {
    throw std::runtime_error(path + ": cannot write image: " + e.what());
  }
  if (!ok) throw std::runtime_error(path + ": cannot write image");
}

ImageU8 ReadImageU8(const std::string& path, int channels) {
  cv::Mat in = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (in.empty()) throw std::runtime_error(path + ": missing or not a decodable image");
  if (in.depth() != CV_8U) {
    throw std::runtime_error(path + ": expected an 8-bit image, found another bit depth");
  }
  int file_channels = in.channels();
  int want = channels == 0 ? (file_channels == 1 ? 1 : 3) : channels;
  if (want != 1 && want != 3) throw std::runtime_error(path + ": can only read as 1 or 3 channels");
  cv::Mat rgb;
  if (want == 1) {
    if (file_channels == 1)
      rgb = in;
    else if (file_channels == 3)
      cv::cvtColor(in, rgb, cv::COLOR_BGR2GRAY);
    else
      cv::cvtColor(in, rgb, cv::COLOR_BGRA2GRAY);
  } else {
    if (file_channels == 1)
      cv::cvtColor(in, rgb, cv::COLOR_GRAY2RGB);
    else if (file_channels == 3)
      cv::cvtColor(in, rgb, cv::COLOR_BGR2RGB);
    else
      cv::cvtColor(in, rgb, cv::COLOR_BGRA2RGB);
  }
  ImageU8 image(rgb.cols, rgb.rows, want);
  for (int y = 0; y < rgb.rows; ++y) {
    const std::uint8_t* row = rgb.ptr<std::uint8_t>(y);
    std::copy(row, row + static_cast<std::size_t>(rgb.cols) * want,
              image.pixels.begin() + static_cast<std::size_t>(y) * rgb.cols * want);
  }
  return image;
}

}  // namespace flamerig
