#pragma once
/// @file Checkpoint.h
/// @brief Checkpoint files: when to write them (`--checkpoint-every N` steps or `Nm` minutes),
/// where (`OUTDIR/<scene name>.checkpoint`), and how: the whole StateArchive in one file, written
/// to a temporary name, flushed to disk and renamed, so a kill at any moment leaves either the
/// previous checkpoint or the new one, never half of one.
#include <frostvdb/core/State.h>

#include <cstdint>
#include <string>

namespace frostvdb {

struct CheckpointPolicy {
    int64_t everySteps = 0;   ///< > 0: at every multiple of this many steps
    double everyMinutes = 0;  ///< > 0: when this much wall time passed since the last one
    bool enabled() const { return everySteps > 0 || everyMinutes > 0; }
    /// "N" (steps, N >= 1) or "Nm" (minutes, N > 0, decimals allowed); throws SceneError.
    static CheckpointPolicy parse(const std::string& text);
};

/// "dir/<name>.checkpoint"
std::string checkpointPath(const std::string& dir, const std::string& sceneName);

/// Writes @a archive atomically (temporary file, fsync, rename, fsync of the folder).
void writeCheckpointFile(const std::string& path, const StateArchive& archive);
/// Reads and verifies (magic, version, checksum) a checkpoint; throws CheckpointError.
StateArchive readCheckpointFile(const std::string& path);

} // namespace frostvdb
