#pragma once
/// @file Png.h
/// @brief Minimal PNG output (libpng): 8-bit RGB previews and 8/16-bit greyscale maps.
/// Written to a temporary name and renamed, like every output file.
#include <cstdint>
#include <string>
#include <vector>

namespace frostvdb {

/// An RGB image, row 0 at the top.
struct ImageRGB {
    int width = 0, height = 0;
    std::vector<uint8_t> rgb; ///< width*height*3
    ImageRGB() = default;
    ImageRGB(int w, int h) : width(w), height(h), rgb(size_t(w) * h * 3, 0) {}
    void set(int x, int y, float r, float g, float b); ///< components in [0,1], clamped
};

void writePngRGB(const std::string& path, const ImageRGB& image);
/// Greyscale, 8 or 16 bits; @a values in [0,1] (clamped), row 0 at the top.
void writePngGray(const std::string& path, int width, int height, const std::vector<float>& values,
                  int bitDepth);

/// A value in [0,1] (clamped) as a 16-bit sample, as writePngGray stores it.
inline uint16_t toSample16(float v) { return uint16_t((v < 0.f ? 0.f : v > 1.f ? 1.f : v) * 65535.0f + 0.5f); }

/// Writes 16-bit samples already quantised (toSample16), row 0 at the top: half the memory of
/// floats for a large displacement tile.
void writePngGray16(const std::string& path, int width, int height, const std::vector<uint16_t>& samples);
/// Reads a PNG as greyscale in [0,1] (colour is converted by luminance); row 0 at the top.
/// Values are the file's code values (8-bit v/255, 16-bit v/65535), without gamma decoding.
/// @a bitDepth, if given, receives 8 or 16 (the precision of the file's samples).
std::vector<float> readPngGray(const std::string& path, int& width, int& height, int* bitDepth = nullptr);

} // namespace frostvdb
