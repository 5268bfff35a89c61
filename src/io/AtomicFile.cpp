#include <frostvdb/io/AtomicFile.h>

#include <atomic>
#include <cerrno>
#include <climits>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <memory>
#include <mutex>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace frostvdb {

namespace {

// ---------------------------------------------------------------------------------------------
// Open temporaries, readable from a signal handler: fixed slots, a path is published before its
// flag is raised, and the handler only calls unlink(2) (async-signal-safe).

constexpr int kSlots = 256;
struct TempSlot {
    std::atomic<int> state{0}; // 0 free, 1 being filled, 2 live
    char path[PATH_MAX];
};
TempSlot gSlots[kSlots];

int registerTemp(const std::string& path)
{
    if (path.size() >= PATH_MAX) return -1;
    for (int i = 0; i < kSlots; ++i) {
        int expected = 0;
        if (gSlots[i].state.compare_exchange_strong(expected, 1)) {
            std::memcpy(gSlots[i].path, path.c_str(), path.size() + 1);
            gSlots[i].state.store(2);
            return i;
        }
    }
    return -1; // still written and removed normally; only the signal cleanup misses it
}

void unregisterTemp(int slot)
{
    if (slot >= 0) gSlots[slot].state.store(0);
}

// What a signal leaves behind (setSignalRecord): published whole through one atomic pointer; the
// previous record stays alive until the next replacement, so a handler reading it on another
// thread never sees freed memory.
struct SignalRecord {
    std::string path, tmp;
    std::string text[3]; // SIGINT, SIGTERM, SIGHUP
};
std::atomic<SignalRecord*> gRecord{nullptr};
std::unique_ptr<SignalRecord> gRecordLive, gRecordRetired;
std::mutex gRecordMutex;

int signalSlot(int sig) { return sig == SIGINT ? 0 : sig == SIGTERM ? 1 : sig == SIGHUP ? 2 : -1; }

/// open/write/fsync/close/rename only: async-signal-safe.
void writeSignalRecord(int sig)
{
    const SignalRecord* r = gRecord.load();
    const int slot = signalSlot(sig);
    if (!r || slot < 0 || r->text[slot].empty()) return;
    const int fd = ::open(r->tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) return;
    const char* p = r->text[slot].data();
    size_t left = r->text[slot].size();
    while (left > 0) {
        const ssize_t n = ::write(fd, p, left);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) { ::close(fd); ::unlink(r->tmp.c_str()); return; }
        p += n;
        left -= size_t(n);
    }
    if (::fsync(fd) != 0 || ::close(fd) != 0) { ::unlink(r->tmp.c_str()); return; }
    if (::rename(r->tmp.c_str(), r->path.c_str()) != 0) ::unlink(r->tmp.c_str());
}

extern "C" void cleanupOnSignal(int sig)
{
    for (auto& s : gSlots)
        if (s.state.load() == 2) ::unlink(s.path);
    writeSignalRecord(sig);
    std::signal(sig, SIG_DFL);
    std::raise(sig);
}

std::mutex gHookMutex;
WriteFaultHook gHook;

int injectedFault(const std::string& path, size_t written)
{
    std::lock_guard<std::mutex> lock(gHookMutex);
    return gHook ? gHook(path, written) : 0;
}

std::string temporaryName(const std::string& path)
{
    static std::atomic<int> counter{0};
    std::filesystem::path p(path);
    return (p.parent_path() / ("." + p.filename().string() + ".tmp" + std::to_string(::getpid()) + "_" +
                               std::to_string(counter++)))
        .string();
}

std::string folderOf(const std::string& path)
{
    const std::string d = std::filesystem::path(path).parent_path().string();
    return d.empty() ? "." : d;
}

} // namespace

AtomicFile::AtomicFile(std::string path) : mPath(std::move(path)), mTmp(temporaryName(mPath))
{
    mSlot = registerTemp(mTmp);
    mFd = ::open(mTmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    if (mFd < 0) {
        const int err = errno;
        unregisterTemp(mSlot);
        mSlot = -1;
        throw WriteError(mPath, std::string("cannot create a temporary file in ") + folderOf(mPath) + ": " +
                                    std::strerror(err));
    }
}

AtomicFile::~AtomicFile()
{
    if (mFd >= 0) ::close(mFd);
    if (!mCommitted) ::unlink(mTmp.c_str());
    unregisterTemp(mSlot);
}

void AtomicFile::fail(const std::string& what, int err)
{
    if (mFd >= 0) ::close(mFd);
    mFd = -1;
    ::unlink(mTmp.c_str());
    throw WriteError(mPath, what + std::strerror(err));
}

void AtomicFile::write(const void* data, size_t bytes)
{
    if (mFd < 0) throw WriteError(mPath, "file already closed");
    writeRange(static_cast<const char*>(data), bytes, nullptr);
}

void AtomicFile::writeAt(size_t offset, const void* data, size_t bytes)
{
    if (mFd < 0) throw WriteError(mPath, "file already closed");
    if (offset + bytes > mWritten) throw WriteError(mPath, "rewrite past the end of what was written");
    writeRange(static_cast<const char*>(data), bytes, &offset);
}

void AtomicFile::writeRange(const char* p, size_t bytes, size_t* offset)
{
    while (bytes > 0) {
        if (int err = injectedFault(mPath, offset ? *offset : mWritten)) fail("", err);
        const size_t chunk = std::min<size_t>(bytes, size_t(1) << 30);
        const ssize_t n = offset ? ::pwrite(mFd, p, chunk, off_t(*offset)) : ::write(mFd, p, chunk);
        if (n < 0) {
            if (errno == EINTR) continue;
            fail("", errno);
        }
        if (n == 0) fail("", EIO);
        p += n;
        bytes -= size_t(n);
        if (offset) *offset += size_t(n);
        else mWritten += size_t(n);
    }
}

void AtomicFile::commit()
{
    if (mFd < 0) throw WriteError(mPath, "file already closed");
    if (int err = injectedFault(mPath, SIZE_MAX)) fail("fsync: ", err);
    if (::fsync(mFd) != 0) fail("fsync: ", errno);
    const int fd = mFd;
    mFd = -1;
    if (::close(fd) != 0) fail("close: ", errno);
    if (::rename(mTmp.c_str(), mPath.c_str()) != 0) fail("rename: ", errno);
    mCommitted = true;
    // Make the rename itself durable; a folder that cannot be opened or synced (some network
    // file systems) does not make the file incomplete, so this is best effort.
    const int dfd = ::open(folderOf(mPath).c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
        ::fsync(dfd);
        ::close(dfd);
    }
}

void writeFileAtomic(const std::string& path, std::string_view bytes)
{
    AtomicFile f(path);
    f.write(bytes);
    f.commit();
}

void setWriteFaultHook(WriteFaultHook hook)
{
    std::lock_guard<std::mutex> lock(gHookMutex);
    gHook = std::move(hook);
}

void setSignalRecord(const std::string& path, const std::string& onSigint, const std::string& onSigterm,
                     const std::string& onSighup)
{
    std::lock_guard<std::mutex> lock(gRecordMutex);
    std::unique_ptr<SignalRecord> r;
    if (!path.empty()) {
        r = std::make_unique<SignalRecord>();
        r->path = path;
        // a temporary name of this process (removed by removeStaleTemporaries if a kill leaves it)
        r->tmp = temporaryName(path);
        r->text[0] = onSigint;
        r->text[1] = onSigterm;
        r->text[2] = onSighup;
    }
    gRecord.store(r.get());
    gRecordRetired = std::move(gRecordLive);
    gRecordLive = std::move(r);
}

void installTempCleanupHandlers()
{
    // Installed at every call (idempotent), so it wins over handlers a host installed since.
    for (int sig : {SIGINT, SIGTERM, SIGHUP}) {
        struct sigaction sa {};
        sa.sa_handler = cleanupOnSignal;
        sigemptyset(&sa.sa_mask);
        sa.sa_flags = SA_RESETHAND;
        ::sigaction(sig, &sa, nullptr);
    }
}

bool isTemporaryName(const std::string& name, long* pid)
{
    if (name.size() < 8 || name[0] != '.') return false;
    const auto t = name.rfind(".tmp");
    if (t == std::string::npos || t < 2) return false;
    const auto us = name.find('_', t + 4);
    if (us == std::string::npos || us == t + 4 || us + 1 == name.size()) return false;
    for (size_t i = t + 4; i < name.size(); ++i)
        if (i != us && !std::isdigit(static_cast<unsigned char>(name[i]))) return false;
    if (pid) *pid = std::strtol(name.c_str() + t + 4, nullptr, 10);
    return true;
}

std::vector<std::string> removeStaleTemporaries(const std::string& dir)
{
    std::vector<std::string> removed;
    std::error_code ec;
    for (auto it = std::filesystem::directory_iterator(dir, ec); !ec && it != std::filesystem::directory_iterator();
         it.increment(ec)) {
        const std::string name = it->path().filename().string();
        long pid = 0;
        if (!isTemporaryName(name, &pid)) continue;
        const bool alive = pid == ::getpid() || (pid > 0 && (::kill(pid_t(pid), 0) == 0 || errno == EPERM));
        if (alive) continue;
        if (::unlink(it->path().c_str()) == 0) removed.push_back(name);
    }
    return removed;
}

} // namespace frostvdb
