#include <frostvdb/core/Progress.h>

#include <cstdio>
#include <unistd.h>

namespace frostvdb {

Progress::Progress(std::string label, int64_t total, std::string unit, bool enabled)
    : mLabel(std::move(label)), mUnit(std::move(unit)), mTotal(total > 0 ? total : 1), mEnabled(enabled),
      mTty(::isatty(STDERR_FILENO)), mStart(std::chrono::steady_clock::now()), mLastDraw(mStart)
{
}

Progress::~Progress()
{
    if (!mFinished && mTty && mEnabled && mDone > 0) std::fprintf(stderr, "\n");
}

void Progress::update(int64_t done)
{
    mDone = done;
    if (!mEnabled) return;
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
    update(mTotal);
    mFinished = true;
    if (mEnabled && mTty) std::fprintf(stderr, "\n");
}

} // namespace frostvdb
