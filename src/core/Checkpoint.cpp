#include <frostvdb/core/Checkpoint.h>
#include <frostvdb/core/Error.h>
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

namespace {
void writeAll(int fd, const std::string& bytes, const std::string& path)
{
    size_t done = 0;
    while (done < bytes.size()) {
        const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) throw CheckpointError(path + ": cannot write checkpoint (" + std::strerror(errno) + ")");
        done += size_t(n);
    }
}
} // namespace

void writeCheckpointFile(const std::string& path, const StateArchive& archive)
{
    const std::string bytes = archive.serialise();
    const std::string dir = std::filesystem::path(path).parent_path().string();
    makeDirectories(dir);
    const std::string tmp = temporaryPathFor(path);
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) throw CheckpointError(tmp + ": cannot create checkpoint (" + std::strerror(errno) + ")");
    try {
        writeAll(fd, bytes, tmp);
        if (::fsync(fd) != 0) throw CheckpointError(tmp + ": fsync failed (" + std::strerror(errno) + ")");
    } catch (...) {
        ::close(fd);
        std::remove(tmp.c_str());
        throw;
    }
    ::close(fd);
    commitTemporary(tmp, path);
    // the rename itself reaches the disk with the folder's entry
    const int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
        ::fsync(dfd);
        ::close(dfd);
    }
}

StateArchive readCheckpointFile(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw CheckpointError(path + ": no checkpoint here (was the run started with --checkpoint-every?)");
    std::stringstream ss;
    ss << in.rdbuf();
    return StateArchive::deserialise(ss.str(), path);
}

int removeStaleTemporaries(const std::string& dir)
{
    namespace fs = std::filesystem;
    static const std::regex pattern(R"(^\..+\.tmp([0-9]+)_[0-9]+$)");
    int removed = 0;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(dir, ec)) {
        std::smatch m;
        const std::string name = e.path().filename().string();
        if (!std::regex_match(name, m, pattern)) continue;
        const long pid = std::stol(m[1].str());
        if (pid == long(::getpid())) continue;
        if (::kill(pid_t(pid), 0) == 0 || errno != ESRCH) continue; // alive (or not ours to judge)
        if (fs::remove(e.path(), ec)) ++removed;
    }
    return removed;
}

} // namespace frostvdb
