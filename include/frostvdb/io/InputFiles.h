#pragma once
/// @file InputFiles.h
/// @brief The files a run reads besides its scene (meshes, textures, seed and melt maps, vector
/// field tables): each must be a regular file (a FIFO or a device would block the run forever, a
/// directory is not a mesh), each read is recorded with a digest of its bytes so that a checkpoint
/// can refuse a resume whose inputs changed, and images are held to the run's memory budget
/// before they are decoded.
///
/// The readers (io/Mesh.h loadMesh, io/Png.h readPngGray, io/VdbIO.h readVdb) call
/// requireRegularFile and noteInputFile themselves; the driver opens an InputFileScope around the
/// scene's set-up and initialisation, so whatever an effect or a domain reads is logged, whoever
/// reads it:
/// @code
///   InputFileLog log;
///   log.memoryLimitBytes = world.memoryLimitBytes;
///   { InputFileScope scope(&log); /* build the domain and the effects */ }
///   log.text(); // "<digest> <bytes> <path>" per file, saved in the checkpoint
/// @endcode
#include <cstdint>
#include <string>
#include <vector>

namespace frostvdb {

/// Throws std::runtime_error "<path>: file not found" or "<path>: not a regular file (a FIFO ...)"
/// unless @a path names a regular file (symbolic links are followed). Never opens the file.
void requireRegularFile(const std::string& path);

/// FNV-1a 64 of the file's bytes as 16 hex digits; throws std::runtime_error when unreadable.
std::string fileDigest(const std::string& path);

struct InputFileRecord {
    std::string path;
    uint64_t bytes = 0;
    std::string digest;
};

/// The input files of one run, in the order they were first read (each path once).
struct InputFileLog {
    std::vector<InputFileRecord> files;
    double memoryLimitBytes = 0; ///< run.memory_limit in bytes (0: none): images are checked against it
    /// Records @a path with its digest now (once per path).
    void note(const std::string& path);
    /// One line per file: "<digest> <bytes> <path>".
    std::string text() const;
    /// Parses text(); lines that do not parse are skipped.
    static std::vector<InputFileRecord> parse(const std::string& text);
};

/// While alive, readers record into @a log (scopes nest; the innermost wins). Not thread-local:
/// the driver reads its inputs on one thread.
class InputFileScope {
public:
    explicit InputFileScope(InputFileLog* log);
    ~InputFileScope();
    InputFileScope(const InputFileScope&) = delete;
    InputFileScope& operator=(const InputFileScope&) = delete;

private:
    InputFileLog* mPrevious;
};

/// Records @a path in the current scope's log (nothing without a scope).
void noteInputFile(const std::string& path);

/// Throws std::runtime_error "<path>: <what> needs about X, more than run.memory_limit allows (Y)"
/// when @a bytes exceed the current scope's memory limit (nothing without a scope or a limit).
void checkInputMemory(const std::string& path, double bytes, const std::string& what);

} // namespace frostvdb
