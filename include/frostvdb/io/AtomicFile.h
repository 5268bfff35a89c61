#pragma once
/// @file AtomicFile.h
/// @brief Writes that cannot lie. Every output file (VDB frames, PNGs, run.json, checkpoints) is
/// written to a hidden temporary beside its final name, each write(2) checked, then fsync'ed,
/// closed, renamed onto the final name and the folder fsync'ed. A failure throws WriteError
/// "<file>: <OS reason>" and removes the temporary; a final name is therefore either absent, the
/// previous complete file, or the new complete file.
///
/// Temporaries are named `.<final name>.tmp<pid>_<n>`: those of this process are removed on
/// SIGINT/SIGTERM (installTempCleanupHandlers) and those of dead processes by
/// removeStaleTemporaries at the next run's start.
#include <cstddef>
#include <functional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace frostvdb {

/// A failed write: what() is one line naming the file and the OS reason.
class WriteError : public std::runtime_error {
public:
    WriteError(const std::string& path, const std::string& reason)
        : std::runtime_error(path + ": write failed (" + reason + ")"), mPath(path) {}
    const std::string& path() const { return mPath; }

private:
    std::string mPath;
};

class AtomicFile {
public:
    /// Creates the temporary beside @a path (the folder must exist). Throws WriteError.
    explicit AtomicFile(std::string path);
    /// Removes the temporary unless commit() succeeded.
    ~AtomicFile();
    AtomicFile(const AtomicFile&) = delete;
    AtomicFile& operator=(const AtomicFile&) = delete;

    /// Appends bytes (retrying partial writes and EINTR). Throws WriteError.
    void write(const void* data, size_t bytes);
    void write(std::string_view s) { write(s.data(), s.size()); }
    /// Overwrites bytes already written, at @a offset (a seekable VDB writes its grid offsets
    /// back). Throws WriteError, also when the range passes the end.
    void writeAt(size_t offset, const void* data, size_t bytes);
    /// Bytes appended so far.
    size_t size() const { return mWritten; }
    /// fsync, close, rename onto the final name, fsync the folder. Throws WriteError.
    void commit();

    const std::string& path() const { return mPath; }
    const std::string& temporaryPath() const { return mTmp; }

private:
    void fail(const std::string& what, int err);
    /// Writes with every return checked: appended (@a offset null) or at *@a offset (advanced).
    void writeRange(const char* p, size_t bytes, size_t* offset);
    std::string mPath, mTmp;
    int mFd = -1;
    int mSlot = -1;
    size_t mWritten = 0;
    bool mCommitted = false;
};

/// Writes @a bytes to @a path atomically (AtomicFile). Throws WriteError.
void writeFileAtomic(const std::string& path, std::string_view bytes);

/// Test hook simulating a failing device: called before each write(2) with the final path and the
/// bytes already written to it, and before fsync/rename with SIZE_MAX; a non-zero return is
/// taken as the errno of that call (e.g. ENOSPC). Pass nullptr to remove it.
using WriteFaultHook = std::function<int(const std::string& path, size_t written)>;
void setWriteFaultHook(WriteFaultHook hook);

/// Installs (once) SIGINT/SIGTERM handlers that remove this process's open temporaries, then
/// let the signal terminate the process as it would have.
void installTempCleanupHandlers();

/// What SIGINT, SIGTERM or SIGHUP leave behind: after removing the temporaries, the handler
/// writes the text for that signal to @a path (through a temporary and a rename, with
/// async-signal-safe calls only) before the signal ends the process. A run keeps its run.json
/// here with "status": "interrupted" and the signal. An empty @a path clears it.
void setSignalRecord(const std::string& path, const std::string& onSigint, const std::string& onSigterm,
                     const std::string& onSighup);
/// Removes temporaries in @a dir left by processes that no longer run; returns their names.
/// Temporaries of live processes are left alone.
std::vector<std::string> removeStaleTemporaries(const std::string& dir);

/// True for a file name of the temporary form `.<name>.tmp<pid>_<n>`; @a pid receives the pid.
bool isTemporaryName(const std::string& filename, long* pid = nullptr);

} // namespace frostvdb
