#pragma once
/// @file Progress.h
/// @brief A progress bar with rate and ETA on a terminal; plain lines (every 10%) in logs.
#include <chrono>
#include <cstdint>
#include <string>

namespace frostvdb {

class Progress {
public:
    /// @a enabled false silences it entirely (tests, --quiet).
    Progress(std::string label, int64_t total, std::string unit = "steps", bool enabled = true);
    ~Progress();
    void update(int64_t done);
    void finish();

private:
    std::string mLabel, mUnit;
    int64_t mTotal, mDone = 0;
    bool mEnabled, mTty, mFinished = false;
    int mLastDecile = -1;
    std::chrono::steady_clock::time_point mStart, mLastDraw;
};

} // namespace frostvdb
