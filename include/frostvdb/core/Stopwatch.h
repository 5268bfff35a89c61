#pragma once
/// @file Stopwatch.h
/// @brief Wall-clock seconds for the timings effects and solvers report, and the process's CPU
/// seconds beside them.
#include <sys/resource.h>

#include <chrono>

namespace frostvdb {

using SteadyClock = std::chrono::steady_clock;

/// Seconds from @a t to now.
inline double secondsSince(SteadyClock::time_point t)
{
    return std::chrono::duration<double>(SteadyClock::now() - t).count();
}

/// User + system CPU seconds of the process, all its threads. Beside a phase's wall time it says
/// how parallel the phase ran (CPU / wall, at most the thread count), and unlike the wall time it
/// does not grow while the process waits for a core on a loaded machine.
inline double processCpuSeconds()
{
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    return double(ru.ru_utime.tv_sec) + 1e-6 * double(ru.ru_utime.tv_usec) + double(ru.ru_stime.tv_sec) +
           1e-6 * double(ru.ru_stime.tv_usec);
}

} // namespace frostvdb
