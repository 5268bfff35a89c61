#pragma once
/// @file Progress.h
/// @brief A progress bar with rate and ETA on a terminal; plain lines (every 10%) in logs; or,
/// for front ends and farm wrappers (`frostvdb run --progress json`), one JSON object per line
/// on stderr:
/// @code
/// {"event":"progress","phase":"simulate","step":40,"steps":300,"frame":1,"frames":3,"elapsed":0.52,"eta":3.38}
/// @endcode
#include <chrono>
#include <cstdint>
#include <string>

namespace frostvdb {

/// How progress is shown: Human (bar on a terminal, 10% lines in logs), Json (JSON lines), None.
enum class ProgressStyle { Human, Json, None };

/// "human", "json", "none" -> the style; throws std::invalid_argument otherwise.
ProgressStyle parseProgressStyle(const std::string& s);

/// A JSON string literal of @a s (quotes, backslashes and control characters escaped).
std::string jsonQuote(const std::string& s);

class Progress {
public:
    /// @a enabled false silences it entirely (tests, --quiet).
    Progress(std::string label, int64_t total, std::string unit = "steps", bool enabled = true);
    /// The same with an explicit style (None silences it).
    Progress(std::string label, int64_t total, std::string unit, ProgressStyle style);
    ~Progress();
    /// @a done units of the total; JSON lines also carry @a frame of @a frames when given (> 0).
    void update(int64_t done, int64_t frame = 0, int64_t frames = 0);
    void finish();
    /// JSON style only: one line {"event": @a event, "phase": @a phase, ..., @a extra} where
    /// @a extra is a comma-prefixed list of JSON members or "" (e.g. `,"file":"a.vdb"`).
    void event(const std::string& event, const std::string& phase, int64_t frame, int64_t frames,
               const std::string& extra = "");
    bool json() const { return mStyle == ProgressStyle::Json; }

private:
    void jsonLine(int64_t frame, int64_t frames, bool force);
    std::string mLabel, mUnit;
    int64_t mTotal, mDone = 0;
    ProgressStyle mStyle;
    bool mEnabled, mTty, mFinished = false;
    int mLastDecile = -1;
    int64_t mFrame = 0, mFrames = 0;
    std::chrono::steady_clock::time_point mStart, mLastDraw;
};

} // namespace frostvdb
