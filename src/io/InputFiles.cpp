/// @file InputFiles.cpp
/// @brief Regular-file checks, digests and the run's log of input files (io/InputFiles.h).
#include <frostvdb/io/InputFiles.h>

#include <frostvdb/base/Budget.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <sstream>
#include <stdexcept>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace frostvdb {

namespace {
std::mutex gMutex;
InputFileLog* gCurrent = nullptr;
} // namespace

void requireRegularFile(const std::string& path)
{
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) {
        const int err = errno;
        if (err == ENOENT || err == ENOTDIR) throw std::runtime_error(path + ": file not found");
        throw std::runtime_error(path + ": cannot read (" + std::strerror(err) + ")");
    }
    if (S_ISREG(st.st_mode)) return;
    const char* kind = S_ISDIR(st.st_mode)    ? "a directory"
                       : S_ISFIFO(st.st_mode) ? "a FIFO (named pipe)"
                       : S_ISCHR(st.st_mode)  ? "a character device"
                       : S_ISBLK(st.st_mode)  ? "a block device"
                       : S_ISSOCK(st.st_mode) ? "a socket"
                                              : "not a file";
    throw std::runtime_error(path + ": not a regular file (" + kind + ")");
}

std::string fileDigest(const std::string& path)
{
    requireRegularFile(path);
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) throw std::runtime_error(path + ": cannot read (" + std::strerror(errno) + ")");
    uint64_t h = 1469598103934665603ull;
    std::vector<unsigned char> buf(size_t(1) << 20);
    while (true) {
        const ssize_t n = ::read(fd, buf.data(), buf.size());
        if (n < 0) {
            if (errno == EINTR) continue;
            const int err = errno;
            ::close(fd);
            throw std::runtime_error(path + ": cannot read (" + std::strerror(err) + ")");
        }
        if (n == 0) break;
        for (ssize_t i = 0; i < n; ++i) {
            h ^= buf[size_t(i)];
            h *= 1099511628211ull;
        }
    }
    ::close(fd);
    char out[17];
    std::snprintf(out, sizeof out, "%016llx", static_cast<unsigned long long>(h));
    return out;
}

void InputFileLog::note(const std::string& path)
{
    for (const auto& f : files)
        if (f.path == path) return;
    InputFileRecord r;
    r.path = path;
    struct stat st {};
    if (::stat(path.c_str(), &st) == 0) r.bytes = uint64_t(st.st_size);
    r.digest = fileDigest(path);
    files.push_back(std::move(r));
}

std::string InputFileLog::text() const
{
    std::string out;
    for (const auto& f : files) out += f.digest + " " + std::to_string(f.bytes) + " " + f.path + "\n";
    return out;
}

std::vector<InputFileRecord> InputFileLog::parse(const std::string& text)
{
    std::vector<InputFileRecord> out;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) {
        const auto a = line.find(' ');
        if (a == std::string::npos) continue;
        const auto b = line.find(' ', a + 1);
        if (b == std::string::npos) continue;
        InputFileRecord r;
        r.digest = line.substr(0, a);
        r.bytes = std::strtoull(line.c_str() + a + 1, nullptr, 10);
        r.path = line.substr(b + 1);
        out.push_back(std::move(r));
    }
    return out;
}

InputFileScope::InputFileScope(InputFileLog* log)
{
    std::lock_guard<std::mutex> lock(gMutex);
    mPrevious = gCurrent;
    gCurrent = log;
}

InputFileScope::~InputFileScope()
{
    std::lock_guard<std::mutex> lock(gMutex);
    gCurrent = mPrevious;
}

void noteInputFile(const std::string& path)
{
    std::lock_guard<std::mutex> lock(gMutex);
    if (gCurrent) gCurrent->note(path);
}

void checkInputMemory(const std::string& path, double bytes, const std::string& what)
{
    double limit = 0;
    {
        std::lock_guard<std::mutex> lock(gMutex);
        if (gCurrent) limit = gCurrent->memoryLimitBytes;
    }
    if (limit <= 0 || !(bytes > limit)) return;
    throw std::runtime_error(path + ": " + what + " needs about " + formatBytes(bytes) +
                             ", more than run.memory_limit allows (" + formatBytes(limit) + ")");
}

} // namespace frostvdb
