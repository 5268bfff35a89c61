#include <frostvdb/core/Progress.h>

#include <cstdio>
#include <stdexcept>
#include <unistd.h>

namespace frostvdb {

ProgressStyle parseProgressStyle(const std::string& s)
{
    if (s == "human") return ProgressStyle::Human;
    if (s == "json") return ProgressStyle::Json;
    if (s == "none") return ProgressStyle::None;
    throw std::invalid_argument("expected human, json or none, got '" + s + "'");
}

std::string jsonQuote(const std::string& s)
{
    std::string out = "\"";
    for (unsigned char c : s) {
        if (c == '"' || c == '\\') {
            out += '\\';
            out += char(c);
        } else if (c < 0x20) {
            char buf[8];
            std::snprintf(buf, sizeof buf, "\\u%04x", c);
            out += buf;
        } else {
            out += char(c);
        }
    }
    return out + "\"";
}

Progress::Progress(std::string label, int64_t total, std::string unit, bool enabled)
    : Progress(std::move(label), total, std::move(unit), enabled ? ProgressStyle::Human : ProgressStyle::None)
{
}

Progress::Progress(std::string label, int64_t total, std::string unit, ProgressStyle style)
    : mLabel(std::move(label)), mUnit(std::move(unit)), mTotal(total > 0 ? total : 1), mStyle(style),
      mEnabled(style != ProgressStyle::None), mTty(style == ProgressStyle::Human && ::isatty(STDERR_FILENO)),
      mStart(std::chrono::steady_clock::now()), mLastDraw(mStart)
{
}

Progress::~Progress()
{
    if (!mFinished && mTty && mEnabled && mDone > 0) std::fprintf(stderr, "\n");
}

void Progress::event(const std::string& event, const std::string& phase, int64_t frame, int64_t frames,
                     const std::string& extra)
{
    if (mStyle != ProgressStyle::Json) return;
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - mStart).count();
    std::fprintf(stderr, "{\"event\":%s,\"phase\":%s,\"step\":%lld,\"steps\":%lld,\"frame\":%lld,\"frames\":%lld,"
                         "\"elapsed\":%.3f%s}\n",
                 jsonQuote(event).c_str(), jsonQuote(phase).c_str(), (long long)mDone, (long long)mTotal,
                 (long long)frame, (long long)frames, elapsed, extra.c_str());
    std::fflush(stderr);
}

void Progress::jsonLine(int64_t frame, int64_t frames, bool force)
{
    const auto now = std::chrono::steady_clock::now();
    // At most ten lines a second, and always the first and the last step and each new frame.
    const bool newFrame = frame != mFrame || frames != mFrames;
    mFrame = frame;
    mFrames = frames;
    if (!force && !newFrame && mDone > 1 && mDone < mTotal &&
        std::chrono::duration<double>(now - mLastDraw).count() < 0.1)
        return;
    mLastDraw = now;
    const double elapsed = std::chrono::duration<double>(now - mStart).count();
    const double rate = elapsed > 0 ? double(mDone) / elapsed : 0.0;
    const double eta = rate > 0 ? double(mTotal - mDone) / rate : -1.0;
    std::fprintf(stderr, "{\"event\":\"progress\",\"phase\":\"simulate\",\"step\":%lld,\"steps\":%lld,\"frame\":%lld,"
                         "\"frames\":%lld,\"elapsed\":%.3f,\"eta\":%.3f}\n",
                 (long long)mDone, (long long)mTotal, (long long)frame, (long long)frames, elapsed, eta);
    std::fflush(stderr);
}

void Progress::update(int64_t done, int64_t frame, int64_t frames)
{
    mDone = done;
    if (!mEnabled) return;
    if (mStyle == ProgressStyle::Json) {
        jsonLine(frame, frames, false);
        return;
    }
    const auto now = std::chrono::steady_clock::now();
    const double elapsed = std::chrono::duration<double>(now - mStart).count();
    const double rate = elapsed > 0 ? double(done) / elapsed : 0.0;
    const double eta = rate > 0 ? double(mTotal - done) / rate : 0.0;
    if (mTty) {
        if (done < mTotal && std::chrono::duration<double>(now - mLastDraw).count() < 0.1) return;
        mLastDraw = now;
        const int width = 30;
        const int filled = int(width * double(done) / double(mTotal));
        std::string bar(size_t(filled), '#');
        bar.resize(width, '.');
        std::fprintf(stderr, "\r%s [%s] %lld/%lld %s  %.1f %s/s  ETA %.0fs   ", mLabel.c_str(), bar.c_str(),
                     (long long)done, (long long)mTotal, mUnit.c_str(), rate, mUnit.c_str(), eta);
        std::fflush(stderr);
    } else {
        const int decile = int(10 * done / mTotal);
        if (decile == mLastDecile) return;
        mLastDecile = decile;
        std::fprintf(stderr, "%s: %lld/%lld %s (%d%%, %.1f %s/s, ETA %.0fs)\n", mLabel.c_str(),
                     (long long)done, (long long)mTotal, mUnit.c_str(), decile * 10, rate, mUnit.c_str(), eta);
    }
}

void Progress::finish()
{
    if (mFinished) return;
    if (mStyle == ProgressStyle::Json) {
        mDone = mTotal;
        mFinished = true;
        return; // the caller reports the end ("done") with what it wrote
    }
    update(mTotal);
    mFinished = true;
    if (mEnabled && mTty) std::fprintf(stderr, "\n");
}

} // namespace frostvdb
