/// @file OutputLock.cpp
/// @brief fcntl record locks on the output folder (io/OutputLock.h).
#include <frostvdb/io/OutputLock.h>
#include <frostvdb/io/AtomicFile.h>

#include <cerrno>
#include <cstring>

#include <fcntl.h>
#include <unistd.h>

namespace frostvdb {

OutputFolderLock::OutputFolderLock(const std::string& dir, int64_t first, int64_t last, bool wait,
                                   const std::function<void(const std::string&)>& onWait)
{
    const std::string path = dir + "/" + fileName();
    mFd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (mFd < 0) throw WriteError(path, std::string("cannot open the output folder's lock file: ") + std::strerror(errno));
    struct flock fl {};
    fl.l_type = F_WRLCK;
    fl.l_whence = SEEK_SET;
    fl.l_start = off_t(first);
    fl.l_len = off_t(last - first + 1);
    while (::fcntl(mFd, F_SETLK, &fl) != 0) {
        const int err = errno;
        if (err == EINTR) continue;
        if (err != EACCES && err != EAGAIN) {
            ::close(mFd);
            mFd = -1;
            throw WriteError(path, std::string("cannot lock the output folder: ") + std::strerror(err));
        }
        struct flock who = fl;
        std::string holder = "another frostvdb run";
        if (::fcntl(mFd, F_GETLK, &who) == 0 && who.l_type != F_UNLCK) {
            holder += " (pid " + std::to_string(who.l_pid);
            if (who.l_len > 0)
                holder += ", frames " + std::to_string(int64_t(who.l_start)) + "-" +
                          std::to_string(int64_t(who.l_start + who.l_len - 1));
            holder += ")";
        }
        const std::string range = first == last ? "frame " + std::to_string(first)
                                                : "frames " + std::to_string(first) + "-" + std::to_string(last);
        if (!wait) {
            ::close(mFd);
            mFd = -1;
            throw OutputBusyError(dir + ": " + holder + " is writing " + range +
                                  " into this folder; wait for it to end (--wait-lock waits) or choose another --out");
        }
        if (onWait) onWait(dir + ": waiting for " + holder + " to release " + range + " (--wait-lock)");
        while (::fcntl(mFd, F_SETLKW, &fl) != 0) {
            if (errno == EINTR) continue;
            const int e2 = errno;
            ::close(mFd);
            mFd = -1;
            throw WriteError(path, std::string("cannot lock the output folder: ") + std::strerror(e2));
        }
        break;
    }
}

OutputFolderLock::~OutputFolderLock()
{
    if (mFd >= 0) ::close(mFd); // releases the record lock
}

} // namespace frostvdb
