#pragma once
/// @file Stopwatch.h
/// @brief Wall-clock seconds for the timings effects and solvers report.
#include <chrono>

namespace frostvdb {

using SteadyClock = std::chrono::steady_clock;

/// Seconds from @a t to now.
inline double secondsSince(SteadyClock::time_point t)
{
    return std::chrono::duration<double>(SteadyClock::now() - t).count();
}

} // namespace frostvdb
