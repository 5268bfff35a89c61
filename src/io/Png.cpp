#include <frostvdb/io/Png.h>
#include <frostvdb/io/InputFiles.h>
#include <frostvdb/io/AtomicFile.h>

#include <png.h>

#include <algorithm>
#include <cstdio>
#include <stdexcept>
#include <functional>
#include <string>

namespace frostvdb {

namespace {

constexpr uint64_t kMaxMapPixels = uint64_t(16384) * 16384;

uint8_t to8(float v) { return uint8_t(std::clamp(v, 0.0f, 1.0f) * 255.0f + 0.5f); }

struct PngWriter {
    png_structp png = nullptr;
    png_infop info = nullptr;
    ~PngWriter()
    {
        if (png) png_destroy_write_struct(&png, info ? &info : nullptr);
    }
};

extern "C" void appendToString(png_structp png, png_bytep data, png_size_t n)
{
    static_cast<std::string*>(png_get_io_ptr(png))->append(reinterpret_cast<const char*>(data), n);
}
extern "C" void noFlush(png_structp) {}

/// Encodes in memory, then writes through AtomicFile (every return checked). @a row(y) gives
/// image row y's bytes (valid until the next call), so a caller need not hold a second copy of
/// a large image in PNG sample format.
void writePng(const std::string& path, int w, int h, int colorType, int bitDepth,
              const std::function<const uint8_t*(int)>& row)
{
    std::string bytes;
    {
        PngWriter pw;
        pw.png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
        if (!pw.png) throw WriteError(path, "libpng could not start");
        pw.info = png_create_info_struct(pw.png);
        if (!pw.info) throw WriteError(path, "libpng could not start");
        if (setjmp(png_jmpbuf(pw.png))) throw WriteError(path, "libpng could not encode the image");
        png_set_write_fn(pw.png, &bytes, appendToString, noFlush);
        png_set_IHDR(pw.png, pw.info, w, h, bitDepth, colorType, PNG_INTERLACE_NONE,
                     PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
        png_write_info(pw.png, pw.info);
        for (int y = 0; y < h; ++y) png_write_row(pw.png, const_cast<png_bytep>(row(y)));
        png_write_end(pw.png, nullptr);
    }
    writeFileAtomic(path, bytes);
}

} // namespace

void ImageRGB::set(int x, int y, float r, float g, float b)
{
    if (x < 0 || y < 0 || x >= width || y >= height) return;
    uint8_t* p = &rgb[(size_t(y) * width + x) * 3];
    p[0] = to8(r);
    p[1] = to8(g);
    p[2] = to8(b);
}

void writePngRGB(const std::string& path, const ImageRGB& image)
{
    const size_t rowBytes = size_t(image.width) * 3;
    writePng(path, image.width, image.height, PNG_COLOR_TYPE_RGB, 8,
             [&](int y) { return image.rgb.data() + size_t(y) * rowBytes; });
}

void writePngGray(const std::string& path, int width, int height, const std::vector<float>& values,
                  int bitDepth)
{
    if (bitDepth != 8 && bitDepth != 16) throw std::invalid_argument("bit depth must be 8 or 16");
    // One row at a time: a 4096^2 displacement tile would need 32 MiB more as a whole.
    std::vector<uint8_t> bytes(size_t(width) * (bitDepth / 8));
    writePng(path, width, height, PNG_COLOR_TYPE_GRAY, bitDepth, [&](int y) {
        const float* in = values.data() + size_t(y) * width;
        for (int x = 0; x < width; ++x) {
            const float v = std::clamp(in[x], 0.0f, 1.0f);
            if (bitDepth == 8) {
                bytes[size_t(x)] = uint8_t(v * 255.0f + 0.5f);
            } else { // PNG stores 16-bit samples big-endian
                const uint16_t s = toSample16(v);
                bytes[2 * size_t(x)] = uint8_t(s >> 8);
                bytes[2 * size_t(x) + 1] = uint8_t(s & 0xff);
            }
        }
        return bytes.data();
    });
}

void writePngGray16(const std::string& path, int width, int height, const std::vector<uint16_t>& samples)
{
    std::vector<uint8_t> bytes(size_t(width) * 2);
    writePng(path, width, height, PNG_COLOR_TYPE_GRAY, 16, [&](int y) {
        const uint16_t* in = samples.data() + size_t(y) * width;
        for (int x = 0; x < width; ++x) { // big-endian
            bytes[2 * size_t(x)] = uint8_t(in[x] >> 8);
            bytes[2 * size_t(x) + 1] = uint8_t(in[x] & 0xff);
        }
        return bytes.data();
    });
}

std::vector<float> readPngGray(const std::string& path, int& width, int& height, int* bitDepth)
{
    requireRegularFile(path); // a FIFO would block libpng's fopen forever
    noteInputFile(path);
    png_image image{};
    image.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&image, path.c_str()))
        throw std::runtime_error(path + ": cannot read PNG (" + image.message + ")");
    // A damaged header can claim any size: refuse before allocating.
    if (uint64_t(image.width) * image.height > kMaxMapPixels) {
        png_image_free(&image);
        throw std::runtime_error(path + ": PNG claims " + std::to_string(image.width) + " x " +
                                 std::to_string(image.height) + " pixels; maps up to 16384 x 16384 are read");
    }
    // Code values as they are: 16-bit files are read as 16-bit grey (libpng treats them as
    // linear, so no conversion), 8-bit files as 8-bit grey (no sRGB-to-linear decoding, which
    // would turn a painted 50% grey into 21%).
    const bool sixteen = (image.format & PNG_FORMAT_FLAG_LINEAR) != 0;
    if (bitDepth) *bitDepth = sixteen ? 16 : 8;
    // What decoding holds at its peak: the decoded samples (1 or 2 bytes) and the floats (4).
    try {
        char what[120];
        std::snprintf(what, sizeof what, "decoding its %u x %u pixels (%d bytes each)", image.width, image.height,
                      sixteen ? 6 : 5);
        checkInputMemory(path, double(image.width) * double(image.height) * (sixteen ? 6.0 : 5.0), what);
    } catch (...) {
        png_image_free(&image);
        throw;
    }
    std::vector<float> out;
    if (sixteen) {
        image.format = PNG_FORMAT_LINEAR_Y;
        std::vector<uint16_t> buf(PNG_IMAGE_SIZE(image) / 2);
        if (!png_image_finish_read(&image, nullptr, buf.data(), 0, nullptr))
            throw std::runtime_error(path + ": cannot decode PNG (" + image.message + ")");
        out.resize(buf.size());
        for (size_t i = 0; i < buf.size(); ++i) out[i] = buf[i] / 65535.0f;
    } else {
        image.format = PNG_FORMAT_GRAY;
        std::vector<uint8_t> buf(PNG_IMAGE_SIZE(image));
        if (!png_image_finish_read(&image, nullptr, buf.data(), 0, nullptr))
            throw std::runtime_error(path + ": cannot decode PNG (" + image.message + ")");
        out.resize(buf.size());
        for (size_t i = 0; i < buf.size(); ++i) out[i] = buf[i] / 255.0f;
    }
    width = int(image.width);
    height = int(image.height);
    return out;
}

} // namespace frostvdb
