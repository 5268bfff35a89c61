#include <frostvdb/core/Checkpoint.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/io/AtomicFile.h>
#include <frostvdb/io/VdbIO.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <signal.h>
#include <sstream>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace frostvdb {

CheckpointPolicy CheckpointPolicy::parse(const std::string& text)
{
    CheckpointPolicy p;
    if (text.empty()) return p;
    auto bad = [&]() -> CheckpointPolicy {
        throw SceneError("--checkpoint-every", 0, "",
                         "expected N (steps, an integer >= 1) or Nm (minutes, > 0, e.g. 30m or 0.5m), got '" + text + "'");
    };
    try {
        size_t used = 0;
        if (text.back() == 'm') {
            const std::string num = text.substr(0, text.size() - 1);
            const double m = std::stod(num, &used);
            if (used != num.size() || !(m > 0) || !std::isfinite(m)) return bad();
            p.everyMinutes = m;
        } else {
            const long long n = std::stoll(text, &used);
            if (used != text.size() || n < 1) return bad();
            p.everySteps = n;
        }
    } catch (const SceneError&) {
        throw;
    } catch (...) {
        return bad();
    }
    return p;
}

std::string checkpointPath(const std::string& dir, const std::string& sceneName)
{
    return dir + (dir.empty() || dir.back() == '/' ? "" : "/") + sceneName + ".checkpoint";
}

void writeCheckpointFile(const std::string& path, const StateArchive& archive)
{
    // io/AtomicFile: temporary, every return checked, fsync, rename, fsync of the folder
    const std::string dir = std::filesystem::path(path).parent_path().string();
    if (!dir.empty()) makeDirectories(dir);
    // a failed write is a WriteError like any other output (exit code 4), naming the checkpoint
    writeFileAtomic(path, archive.serialise());
}

StateArchive readCheckpointFile(const std::string& path)
{
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0)
        throw CheckpointError(path + ": no checkpoint here (was the run started with --checkpoint-every?)");
    if (!S_ISREG(st.st_mode)) // a FIFO would block the read forever
        throw CheckpointError(path + ": not a regular file (" +
                              (S_ISDIR(st.st_mode) ? "a directory" : S_ISFIFO(st.st_mode) ? "a FIFO" : "a device") +
                              "); a checkpoint is a file written by --checkpoint-every");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw CheckpointError(path + ": no checkpoint here (was the run started with --checkpoint-every?)");
    std::stringstream ss;
    ss << in.rdbuf();
    return StateArchive::deserialise(ss.str(), path);
}

} // namespace frostvdb
