// Pictures for the reports: labelled grids of images, colour maps with their colour bars, and
// scale bars, so that every picture a command writes says what each panel is and what its colours
// mean. Drawn with OpenCV (its Hershey fonts), returned as 8-bit RGB images (core/image.h).
//
// The colour maps: temperature on "inferno" (dark red to yellow-white, as hot things look),
// differences on a blue-white-red diverging map (blue too cold, red too hot), sigmas and Delta E on
// "viridis" (ordered, legible to people with common colour-vision deficiencies).
#ifndef FLAMERIG_PIPELINE_PICTURE_H_
#define FLAMERIG_PIPELINE_PICTURE_H_

#include <array>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/image.h"

namespace flamerig {

using Rgb = std::array<std::uint8_t, 3>;

// Colour maps of u in [0, 1] (clamped).
Rgb InfernoColour(double u);
Rgb ViridisColour(double u);
// e / range in [-1, 1] (clamped): blue below zero, white at zero, red above.
Rgb DivergingColour(double e, double range);

// A vertical colour bar `height` pixels tall for values lo (bottom) to hi (top): five ticks,
// each "value unit" (a "+" on positive values when `signed_ticks`), and `title` above it.
struct ColourScale {
  std::string title;  // e.g. "Delta E", "K"
  std::string unit;   // after each tick value, e.g. "K"; may be empty
  double lo = 0, hi = 1;
  std::function<Rgb(double)> colour;  // of a value in [lo, hi]
  bool signed_ticks = false;
  int decimals = 0;  // of each tick value
};
ImageU8 ColourBar(const ColourScale& scale, int height);

// A labelled grid: an optional title, a label over each column, a label above each row, each tile
// scaled to `tile_height` keeping its aspect (grey promoted to RGB), colour bars to the right of
// the rows, white background. rows[r][c] may be an empty image (a blank cell).
struct PictureGrid {
  std::string title;
  std::vector<std::string> column_labels;
  std::vector<std::string> row_labels;
  std::vector<std::vector<ImageU8>> rows;
  int tile_height = 240;
  std::vector<ColourScale> bars;  // each as tall as one row of tiles
};
ImageU8 DrawPictureGrid(const PictureGrid& grid);

// `image` with `label` written above it on white; a "\n" in it starts another line. The picture
// is widened (white on the right) where the label needs it.
ImageU8 Labelled(const ImageU8& image, const std::string& label);
// Images side by side (top-aligned) or stacked (left-aligned), `gap` pixels of white apart.
ImageU8 Beside(const std::vector<ImageU8>& images, int gap);
ImageU8 Stacked(const std::vector<ImageU8>& images, int gap);

// Draws a horizontal scale bar of `length_m` metres at `pixels_per_m` in the image's bottom-left
// corner, white with a dark outline and its length written beside it ("1 cm", "5 mm").
void DrawScaleBar(ImageU8* image, double pixels_per_m, double length_m);
// A round length (1, 2 or 5 times a power of ten metres) drawn 40 to 100 pixels long.
double ScaleBarLength(double pixels_per_m);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_PICTURE_H_
