#pragma once
/// @file OutputLock.h
/// @brief The lock a run holds on its output folder, so two runs never write the same frames
/// into one folder at once (their frames would mix and run.json would describe only one).
///
/// An advisory POSIX record lock (fcntl) on `OUT/.frostvdb.run.lock`, over the byte range
/// [first frame, last frame]: runs of overlapping frame ranges exclude each other, while farm
/// chunks of disjoint ranges (`--frames 1-6`, `--frames 7-12`) write into one folder side by side.
/// The kernel releases the lock when the process ends in any way (exit, crash, kill -9), so a
/// stale lock cannot outlive its run. Locks are per process: two runs inside one process do
/// not exclude each other (the command line runs one).
#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>

namespace frostvdb {

/// The folder is locked by another run: one line naming the folder, the holder's pid and frames.
class OutputBusyError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

class OutputFolderLock {
public:
    /// Locks frames [@a first, @a last] of @a dir (which must exist). Without @a wait a range held by
    /// another process throws OutputBusyError; with @a wait, @a onWait is called once with a line
    /// saying whom it waits for, then the call blocks until the range is free. Other failures
    /// (a read-only folder) throw WriteError.
    OutputFolderLock(const std::string& dir, int64_t first, int64_t last, bool wait,
                     const std::function<void(const std::string&)>& onWait = {});
    ~OutputFolderLock();
    OutputFolderLock(const OutputFolderLock&) = delete;
    OutputFolderLock& operator=(const OutputFolderLock&) = delete;

    /// The lock file's name inside the folder.
    static const char* fileName() { return ".frostvdb.run.lock"; }

private:
    int mFd = -1;
};

} // namespace frostvdb
