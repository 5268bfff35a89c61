#include <frostvdb/io/VdbIO.h>
#include <frostvdb/io/InputFiles.h>
#include <frostvdb/base/Error.h>
#include <frostvdb/io/AtomicFile.h>
#include <frostvdb/io/StreamedGrid.h>

#include <openvdb/io/Archive.h>
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/io/Stream.h>
#include <openvdb/io/io.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <sstream>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <functional>
#include <set>

#include <csignal>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

namespace frostvdb {

std::string framePath(const std::string& dir, const std::string& name, int64_t frame, const std::string& ext)
{
    std::ostringstream os;
    os << dir << (dir.empty() || dir.back() == '/' ? "" : "/") << name << "." << std::setw(4)
       << std::setfill('0') << frame << "." << ext;
    return os.str();
}

namespace {
template <typename GridT>
bool checkGrid(const openvdb::GridBase& base)
{
    auto grid = dynamic_cast<const GridT*>(&base);
    if (!grid) return false;
    auto finite = [](const auto& v) {
        using V = std::decay_t<decltype(v)>;
        if constexpr (std::is_floating_point_v<V>) return std::isfinite(v);
        else return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
    };
    if (!finite(grid->background()))
        throw SimulationError("grid '" + grid->getName() + "': non-finite background value");
    for (auto it = grid->cbeginValueOn(); it; ++it) {
        if (!finite(*it)) {
            std::ostringstream os;
            os << "grid '" << grid->getName() << "' holds a non-finite value at voxel " << it.getCoord()
               << "; refusing to write it";
            throw SimulationError(os.str());
        }
    }
    return true;
}
} // namespace

void checkFinite(const openvdb::GridBase& grid)
{
    if (dynamic_cast<const StreamedFloatGrid*>(&grid)) return; // checked leaf by leaf as it is written
    checkGrid<openvdb::FloatGrid>(grid) || checkGrid<openvdb::DoubleGrid>(grid) ||
        checkGrid<openvdb::Vec3SGrid>(grid);
}

// ---------------------------------------------------------------------------------------------
// Reading hostile files: validate the layout against the file length before OpenVDB allocates.

std::string shortMessage(std::string s, size_t maxChars)
{
    for (auto& c : s)
        if (c == '\n' || c == '\r' || c == '\t') c = ' ';
        else if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) == 0x7f) c = '?';
    if (s.size() > maxChars) s = s.substr(0, maxChars - 3) + "...";
    return s;
}

VdbFileError::VdbFileError(const std::string& path, const std::string& reason)
    : std::runtime_error(shortMessage(path, 200) + ": not a readable VDB file (" + shortMessage(reason, 200) + ")")
{
}

namespace {

/// Bounds-checked reads over the file's bytes; every failure names what was being read.
class Cursor {
public:
    Cursor(const std::string& path, const std::string& bytes) : mPath(path), mBytes(bytes) {}
    size_t pos() const { return mPos; }
    size_t remaining() const { return mBytes.size() - mPos; }
    template <typename T>
    T read(const char* what)
    {
        need(sizeof(T), what);
        T v;
        std::memcpy(&v, mBytes.data() + mPos, sizeof(T));
        mPos += sizeof(T);
        return v;
    }
    std::string readString(const char* what)
    {
        const uint32_t n = read<uint32_t>(what);
        need(n, what);
        std::string s = mBytes.substr(mPos, n);
        mPos += n;
        return s;
    }
    void skip(size_t n, const char* what)
    {
        need(n, what);
        mPos += n;
    }
    void seek(size_t p) { mPos = p; }
    [[noreturn]] void fail(const std::string& why) const
    {
        throw VdbFileError(mPath, why + " at byte " + std::to_string(mPos) + " of " + std::to_string(mBytes.size()));
    }

private:
    void need(size_t n, const char* what) const
    {
        if (n > remaining())
            fail(std::string(what) + " needs " + std::to_string(n) + " bytes but the file ends");
    }
    const std::string& mPath;
    const std::string& mBytes;
    size_t mPos = 0;
};

/// A read-only, seekable stream buffer over bytes already in memory.
class SpanBuf : public std::streambuf {
public:
    SpanBuf(const char* data, size_t n)
    {
        char* p = const_cast<char*>(data);
        setg(p, p, p + n);
    }

protected:
    pos_type seekoff(off_type off, std::ios_base::seekdir dir, std::ios_base::openmode which) override
    {
        if (!(which & std::ios_base::in)) return pos_type(off_type(-1));
        const off_type size = egptr() - eback();
        const off_type base = dir == std::ios_base::beg ? 0 : dir == std::ios_base::cur ? gptr() - eback() : size;
        const off_type p = base + off;
        if (p < 0 || p > size) return pos_type(off_type(-1));
        setg(eback(), eback() + p, egptr());
        return pos_type(p);
    }
    pos_type seekpos(pos_type pos, std::ios_base::openmode which) override
    {
        return seekoff(off_type(pos), std::ios_base::beg, which);
    }
};

void readHeader(Cursor& c, VdbLayout& out)
{
    if (c.remaining() < 8 || c.read<int64_t>("the magic number") != int64_t(openvdb::OPENVDB_MAGIC)) {
        c.seek(0);
        c.fail("no VDB magic number");
    }
    out.fileVersion = c.read<uint32_t>("the format version");
    if (out.fileVersion < openvdb::OPENVDB_FILE_VERSION_BOOST_UUID || out.fileVersion > openvdb::OPENVDB_FILE_VERSION)
        c.fail("format version " + std::to_string(out.fileVersion) + " outside the supported " +
               std::to_string(openvdb::OPENVDB_FILE_VERSION_BOOST_UUID) + "-" +
               std::to_string(openvdb::OPENVDB_FILE_VERSION));
    c.read<uint32_t>("the library major version");
    c.read<uint32_t>("the library minor version");
    const char offsets = c.read<char>("the grid offsets flag");
    if (offsets != 0 && offsets != 1) c.fail("grid offsets flag is neither 0 nor 1");
    out.hasOffsets = offsets == 1;
    if (out.fileVersion >= openvdb::OPENVDB_FILE_VERSION_SELECTIVE_COMPRESSION &&
        out.fileVersion < openvdb::OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION)
        c.read<char>("the compression flag");
    c.skip(36, "the file UUID");
}

/// MetaMap layout: count, then (name, type name, byte count, bytes) per entry.
void readMetaMap(Cursor& c, const char* what)
{
    const uint32_t count = c.read<uint32_t>(what);
    if (uint64_t(count) * 12 > c.remaining()) c.fail(std::string(what) + ": " + std::to_string(count) + " entries cannot fit");
    for (uint32_t i = 0; i < count; ++i) {
        c.readString("a metadata name");
        c.readString("a metadata type");
        const uint32_t n = c.read<uint32_t>("a metadata size");
        c.skip(n, "a metadata value");
    }
}

void readDescriptors(Cursor& c, VdbLayout& out, size_t fileSize)
{
    const int32_t count = c.read<int32_t>("the grid count");
    if (count < 0 || uint64_t(count) * 36 > c.remaining())
        c.fail("grid count " + std::to_string(count) + " cannot fit");
    out.gridCount = count;
    for (int32_t i = 0; i < count; ++i) {
        VdbGridSpan g;
        g.name = openvdb::io::GridDescriptor::nameAsString(c.readString("a grid name"));
        g.type = c.readString("a grid type");
        const std::string half = "_HalfFloat";
        const std::string base = g.type.size() > half.size() && g.type.compare(g.type.size() - half.size(), half.size(), half) == 0
                                     ? g.type.substr(0, g.type.size() - half.size()) : g.type;
        if (!openvdb::GridBase::isRegistered(base)) c.fail("grid '" + g.name + "' has unknown type '" + g.type + "'");
        if (out.fileVersion >= openvdb::OPENVDB_FILE_VERSION_GRID_INSTANCING) c.readString("an instance parent name");
        g.half = base != g.type;
        g.gridPos = c.read<int64_t>("a grid position");
        g.blockPos = c.read<int64_t>("a grid data position");
        g.endPos = c.read<int64_t>("a grid end position");
        out.grids.push_back(g);
        if (!out.hasOffsets) return; // a plain stream: grids follow inline, nothing to check against
        if (g.gridPos != int64_t(c.pos()) || g.blockPos < g.gridPos || g.endPos < g.blockPos ||
            uint64_t(g.endPos) > fileSize)
            c.fail("grid '" + g.name + "' claims bytes " + std::to_string(g.gridPos) + "-" + std::to_string(g.endPos) +
                   " (the file is truncated or damaged)");
        // Each grid starts with its own compression flags (Archive::setGridCompression).
        if (out.fileVersion >= openvdb::OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION && g.blockPos - g.gridPos >= 4)
            out.grids.back().compression = c.read<uint32_t>("a grid's compression flags");
        c.seek(size_t(g.endPos));
    }
}

} // namespace

uint32_t compressionFlags(const std::string& name)
{
    if (name == "blosc") return openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK;
    if (name == "zip") return openvdb::io::COMPRESS_ZIP | openvdb::io::COMPRESS_ACTIVE_MASK;
    if (name == "none") return openvdb::io::COMPRESS_NONE;
    throw std::invalid_argument("expected blosc, zip or none, got '" + name + "'");
}

std::string compressionText(uint32_t flags)
{
    std::string out;
    auto add = [&](const char* s) { out += (out.empty() ? "" : " + ") + std::string(s); };
    if (flags & openvdb::io::COMPRESS_BLOSC) add("blosc");
    if (flags & openvdb::io::COMPRESS_ZIP) add("zip");
    if (flags & openvdb::io::COMPRESS_ACTIVE_MASK) add("active mask");
    return out.empty() ? "none" : out;
}

std::string readWholeFile(const std::string& path)
{
    std::error_code ec;
    if (std::filesystem::is_directory(path, ec)) throw VdbFileError(path, "is a folder");
    try {
        requireRegularFile(path); // a FIFO or a device would block the read forever
    } catch (const std::runtime_error& e) {
        const std::string m = e.what();
        throw VdbFileError(path, m.substr(std::min(m.size(), path.size() + 2)));
    }
    std::ifstream in(path, std::ios::binary);
    if (!in) throw VdbFileError(path, std::string("cannot open: ") + std::strerror(errno));
    const auto size = std::filesystem::file_size(path, ec);
    if (ec) throw VdbFileError(path, "cannot read its size: " + ec.message());
    std::string bytes(size, '\0');
    if (size > 0 && !in.read(bytes.data(), std::streamsize(size)))
        throw VdbFileError(path, "read error after " + std::to_string(in.gcount()) + " bytes");
    return bytes;
}

VdbLayout validateVdb(const std::string& path, const std::string& bytes)
{
    VdbLayout out;
    Cursor c(path, bytes);
    readHeader(c, out);
    readMetaMap(c, "the file metadata");
    readDescriptors(c, out, bytes.size());
    return out;
}

void makeDirectories(const std::string& dir)
{
    std::error_code ec;
    if (!dir.empty()) std::filesystem::create_directories(dir, ec);
    if (ec) throw WriteError(dir, "cannot create the directory: " + ec.message());
}

namespace {

/// OpenVDB writes seekable files (grid offsets, as io::File does) only through Archive's
/// protected writer; this exposes it for a memory stream, so the bytes are those of io::File.
class MemoryArchive : public openvdb::io::Archive {
public:
    void writeTo(std::ostream& os, const openvdb::GridPtrVec& grids, const openvdb::MetaMap& meta) const
    {
        Archive::write(os, grids, /*seekable=*/true, meta);
    }

    /// What Archive::write does for grids with distinct names and trees (header, file metadata,
    /// grid count, then each grid with its descriptor and offsets), but asking @a next for one
    /// grid at a time: a frame's grids need not all exist at once.
    void writeStreamed(std::ostream& os, size_t count, const std::function<openvdb::GridBase::ConstPtr(size_t)>& next,
                       const openvdb::MetaMap& meta) const
    {
        // setCompression is the archive's; io::File does the same with its own setting.
        openvdb::io::setVersion(os, openvdb::VersionId(openvdb::OPENVDB_LIBRARY_MAJOR_VERSION, openvdb::OPENVDB_LIBRARY_MINOR_VERSION),
                                openvdb::OPENVDB_FILE_VERSION);
        openvdb::io::setDataCompression(os, compression());
        openvdb::io::setWriteGridStatsMetadata(os, isGridStatsMetadataEnabled());
        writeHeader(os, /*seekable=*/true);
        meta.writeMeta(os);
        const int32_t n = int32_t(count);
        os.write(reinterpret_cast<const char*>(&n), sizeof(n));
        std::set<std::string> names;
        for (size_t i = 0; i < count; ++i) {
            const openvdb::GridBase::ConstPtr grid = next(i);
            if (grid->getName().empty() || !names.insert(grid->getName()).second)
                throw std::logic_error("writeVdbStreamed: grid names must be distinct and not empty ('" +
                                       grid->getName() + "')");
            openvdb::io::GridDescriptor gd(grid->getName(), grid->type(), grid->saveFloatAsHalf());
            if (const auto* streamed = dynamic_cast<const StreamedFloatGrid*>(grid.get()))
                writeStreamedGrid(gd, *streamed, os);
            else
                writeGrid(gd, grid, os, /*seekable=*/true);
            openvdb::io::setDataCompression(os, compression()); // per-grid options reset, as Archive::write does
        }
    }

private:
    /// Archive::writeGrid (OpenVDB 10.0, seekable) for a StreamedFloatGrid: the same steps and
    /// bytes, but the `file_delayed_load` metadata from the grid's own values
    /// (StreamedFloatGrid::delayedLoadMetadata) where OpenVDB would read its empty leaf buffers.
    /// writeStreamed sets no stream metadata of its own: the grid's is cleared afterwards.
    void writeStreamedGrid(openvdb::io::GridDescriptor& gd, const StreamedFloatGrid& grid, std::ostream& os) const
    {
        // the stream holds the address of this pointer until it is cleared, before the pointer goes
        auto streamMetadata = std::make_shared<openvdb::io::StreamMetadata>();
        streamMetadata->setHalfFloat(grid.saveFloatAsHalf());
        streamMetadata->gridMetadata() = static_cast<const openvdb::MetaMap&>(grid);
        struct ClearOnExit {
            std::ostream& os;
            ~ClearOnExit() { openvdb::io::clearStreamMetadataPtr(os); }
        } clear{os};
        openvdb::io::setStreamMetadataPtr(os, streamMetadata, /*transfer=*/false);
        gd.writeHeader(os);
        const int64_t offsetPos = int64_t(os.tellp());
        gd.writeStreamPos(os); // the offsets, written again once known
        gd.setGridPos(os.tellp());
        setGridCompression(os, grid);
        const auto copy = openvdb::ConstPtrCast<openvdb::GridBase>(grid.copyGrid()); // shallow: the metadata written
        copy->insertMeta(openvdb::GridBase::META_FILE_DELAYED_LOAD, grid.delayedLoadMetadata(compression()));
        if (openvdb::io::getWriteGridStatsMetadata(os)) {
            copy->addStatsMetadata();
            copy->insertMeta(openvdb::GridBase::META_FILE_COMPRESSION,
                             openvdb::StringMetadata(openvdb::io::compressionToString(openvdb::io::getDataCompression(os))));
        }
        copy->writeMeta(os);
        grid.writeTransform(os);
        grid.writeTopology(os);
        gd.setBlockPos(os.tellp());
        grid.writeBuffers(os);
        gd.setEndPos(os.tellp());
        os.seekp(offsetPos, std::ios_base::beg);
        gd.writeStreamPos(os);
        gd.seekToEnd(os);
    }
};

/// An output stream buffer over an AtomicFile, seekable within what was written (a seekable
/// VDB writes each grid's offsets back after the grid). OpenVDB's writer does not look at
/// stream errors, so the first failure is kept here (the stream turns bad and writes nothing
/// more) and rethrown once the writer returns.
class AtomicFileBuf : public std::streambuf {
public:
    explicit AtomicFileBuf(AtomicFile& file) : mFile(file), mBuffer(size_t(4) << 20)
    {
        setp(mBuffer.data(), mBuffer.data() + mBuffer.size());
    }
    /// Writes what is buffered; rethrows the first failure.
    void finish()
    {
        flushBuffer();
        if (mError) std::rethrow_exception(mError);
    }

protected:
    int_type overflow(int_type c) override
    {
        if (!flushBuffer()) return traits_type::eof();
        if (!traits_type::eq_int_type(c, traits_type::eof())) {
            *pptr() = traits_type::to_char_type(c);
            pbump(1);
        }
        return traits_type::not_eof(c);
    }
    int sync() override { return flushBuffer() ? 0 : -1; }
    pos_type seekoff(off_type off, std::ios_base::seekdir dir, std::ios_base::openmode which) override
    {
        if (!(which & std::ios_base::out)) return pos_type(off_type(-1));
        const off_type here = off_type(mAt + size_t(pptr() - pbase()));
        if (dir == std::ios_base::cur && off == 0) return pos_type(here); // tellp
        if (!flushBuffer()) return pos_type(off_type(-1));
        const off_type target = dir == std::ios_base::beg ? off
                              : dir == std::ios_base::cur ? here + off
                                                          : off_type(mFile.size()) + off;
        if (target < 0 || size_t(target) > mFile.size()) return pos_type(off_type(-1));
        mAt = size_t(target);
        return pos_type(target);
    }
    pos_type seekpos(pos_type pos, std::ios_base::openmode which) override
    {
        return seekoff(off_type(pos), std::ios_base::beg, which);
    }

private:
    /// Writes the buffer at mAt: appended at the end, or over bytes already written after a
    /// seek back (any part past the end is appended).
    bool flushBuffer()
    {
        if (mError) return false;
        try {
            const char* p = pbase();
            size_t n = size_t(pptr() - pbase());
            if (mAt < mFile.size()) {
                const size_t over = std::min(n, mFile.size() - mAt);
                mFile.writeAt(mAt, p, over);
                p += over;
                n -= over;
                mAt += over;
            }
            if (n) {
                mFile.write(p, n);
                mAt += n;
            }
        } catch (...) {
            mError = std::current_exception();
            return false;
        }
        setp(mBuffer.data(), mBuffer.data() + mBuffer.size());
        return true;
    }
    AtomicFile& mFile;
    size_t mAt = 0; ///< file offset of the buffer's first byte
    std::vector<char> mBuffer;
    std::exception_ptr mError;
};

} // namespace

void writeVdbStreamed(const std::string& path, size_t count,
                      const std::function<openvdb::GridBase::Ptr(size_t)>& next, const openvdb::MetaMap& fileMeta,
                      bool halfFloat, uint32_t compression)
{
    AtomicFile file(path); // the final name is untouched until commit
    AtomicFileBuf buf(file);
    std::ostream os(&buf);
    MemoryArchive archive;
    archive.setCompression(compression);
    archive.writeStreamed(os, count, [&](size_t i) -> openvdb::GridBase::ConstPtr {
        openvdb::GridBase::Ptr g = next(i);
        checkFinite(*g);
        g->setSaveFloatAsHalf(halfFloat);
        return g;
    }, fileMeta);
    os.flush();
    buf.finish();
    if (!os) throw WriteError(path, "could not serialise the grids");
    file.commit();
}

void writeVdbAtomic(const std::string& path, const openvdb::GridPtrVec& grids,
                    const openvdb::MetaMap& fileMeta, bool halfFloat, uint32_t compression)
{
    // writeVdbStreamed checks each grid before writing it; a failure leaves the final name untouched.
    writeVdbStreamed(path, grids.size(), [&](size_t i) { return grids[i]; }, fileMeta, halfFloat, compression);
}

namespace {

/// Parses @a bytes with OpenVDB's stream reader; throws what it throws.
openvdb::GridPtrVecPtr parseGrids(const std::string& bytes, openvdb::MetaMap::Ptr* fileMeta)
{
    // A stream that throws on any read past the end, so a damaged count cannot make OpenVDB
    // loop on a failed stream allocating nodes.
    SpanBuf buf(bytes.data(), bytes.size());
    std::istream is(&buf);
    is.exceptions(std::ios::failbit | std::ios::badbit | std::ios::eofbit);
    openvdb::io::Stream stream(is, /*delayLoad=*/false);
    auto grids = stream.getGrids();
    if (!grids) grids = std::make_shared<openvdb::GridPtrVec>();
    if (fileMeta) *fileMeta = stream.getMetadata();
    if (fileMeta && !*fileMeta) *fileMeta = std::make_shared<openvdb::MetaMap>();
    return grids;
}

/// The state letter of process @a pid in /proc (R running, S sleeping, ...), or 0.
char processState(pid_t pid)
{
    std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
    std::string text;
    std::getline(in, text);
    const auto close = text.rfind(')'); // the command name may hold spaces
    return close != std::string::npos && close + 2 < text.size() ? text[close + 2] : 0;
}

/// Environment variable that turns a fresh process into a trial parser: "IN,OUT", two file
/// descriptors (see trialParseInFreshProcess).
constexpr const char* kTrialFdVariable = "FROSTVDB_VDB_TRIAL_FD";

/// Writes all of @a text to @a fd; false on any failure.
bool writeAll(int fd, const std::string& text)
{
    for (size_t done = 0; done < text.size();) {
        const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
        if (n <= 0) return false;
        done += size_t(n);
    }
    return true;
}

/// Everything in @a fd from offset 0 (pread: a forked child shares the descriptor's offset).
std::string readAllFrom(int fd)
{
    std::string text;
    char chunk[1 << 16];
    off_t at = 0;
    for (ssize_t n; (n = ::pread(fd, chunk, sizeof chunk, at)) > 0; at += n) text.append(chunk, size_t(n));
    return text;
}

/// The trial parse itself, run in a child: caps memory and CPU, parses @a bytes and writes to
/// @a outFd either the grids serialised again by OpenVDB's writer (exit 0) or the one-line reason
/// the parse failed (exit 3); exit 4 when it asks for too much memory; a crash or SIGXCPU is the
/// verdict on a hostile file. A damaged file can corrupt the heap without crashing the parse,
/// so this process's "it parsed" proves nothing about memory safety: the caller parses only the
/// bytes written back here, which OpenVDB's writer made self-consistent. Never returns.
[[noreturn]] void trialParseAndExit(const std::string& bytes, int outFd)
{
    for (int sig : {SIGSEGV, SIGABRT, SIGBUS, SIGFPE, SIGILL}) std::signal(sig, SIG_DFL);
    long pages = 0, dummy = 0;
    if (FILE* f = std::fopen("/proc/self/statm", "r")) {
        if (std::fscanf(f, "%ld %ld", &pages, &dummy) != 2) pages = 0;
        std::fclose(f);
    }
    const double extra = 2.0 * 1024 * 1024 * 1024 + 64.0 * double(bytes.size());
    rlimit lim{};
    lim.rlim_cur = lim.rlim_max = rlim_t(double(pages) * double(::sysconf(_SC_PAGESIZE)) + extra);
    if (pages > 0) ::setrlimit(RLIMIT_AS, &lim);
    rlimit cpu{};
    cpu.rlim_cur = 30; // SIGXCPU after 30 s of CPU
    cpu.rlim_max = 31;
    ::setrlimit(RLIMIT_CPU, &cpu);
    std::string reason;
    try {
        openvdb::MetaMap::Ptr meta;
        const auto grids = parseGrids(bytes, &meta);
        std::ostringstream os(std::ios::binary);
        MemoryArchive().writeTo(os, *grids, *meta);
        ::_exit(os && writeAll(outFd, std::move(os).str()) ? 0 : 5);
    } catch (const std::bad_alloc&) {
        ::_exit(4);
    } catch (const std::ios_base::failure&) {
        reason = "damaged grid data (a read runs past the end of the file)";
    } catch (const std::exception& e) {
        reason = std::string("damaged grid data (") + e.what() + ")";
    } catch (...) {
        reason = "damaged grid data";
    }
    ::_exit(writeAll(outFd, reason) ? 3 : 5);
}

/// Runs before main() in every program that links this file: a process started by
/// trialParseInFreshProcess() parses the bytes behind the descriptor and exits, so it never
/// reaches the program's own main().
__attribute__((constructor)) void trialParserEntryPoint()
{
    const char* fdText = std::getenv(kTrialFdVariable);
    if (!fdText) return;
    int inFd = -1, outFd = -1;
    if (std::sscanf(fdText, "%d,%d", &inFd, &outFd) != 2) ::_exit(5);
    const std::string bytes = readAllFrom(inFd);
    openvdb::initialize();
    trialParseAndExit(bytes, outFd);
}

/// What a trial child found: @a reason is empty when the file parsed; then @a clean holds the
/// grids as OpenVDB's writer serialised them again in the child.
struct TrialResult {
    std::string reason;
    std::string clean;
    bool stuck = false; ///< the child slept for a whole second and was killed (no verdict)
};

/// Waits for a trial child that writes its result to @a outFd.
TrialResult awaitTrial(pid_t pid, int outFd, bool detectStuck)
{
    TrialResult t;
    int status = 0, sleepingPolls = 0;
    for (int i = 0; i < 12000; ++i) { // 120 s of wall time as a last resort
        const pid_t r = ::waitpid(pid, &status, WNOHANG);
        if (r == pid) {
            const int code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
            if (WIFSIGNALED(status) && WTERMSIG(status) == SIGXCPU)
                t.reason = "damaged grid data (parsing it takes more than 30 s)";
            else if (WIFSIGNALED(status))
                t.reason = "damaged grid data (parsing it crashed OpenVDB's reader)";
            else if (code == 4)
                t.reason = "damaged grid data (it asks for more than 64x its size in memory)";
            else if (code == 3)
                t.reason = readAllFrom(outFd);
            else if (code == 0)
                t.clean = readAllFrom(outFd);
            else
                t.reason = "the file could not be checked (the check process failed)";
            if (code == 3 && t.reason.empty()) t.reason = "damaged grid data";
            return t;
        }
        if (r < 0) {
            t.reason = "the file could not be checked (lost the check process)";
            return t;
        }
        sleepingPolls = detectStuck && processState(pid) == 'S' ? sleepingPolls + 1 : 0;
        if (sleepingPolls >= 100) break; // asleep for 1 s: stuck, not parsing
        ::usleep(10000);
    }
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
    t.stuck = sleepingPolls >= 100;
    if (!t.stuck) t.reason = "damaged grid data (parsing it takes more than 30 s)";
    return t;
}

/// A memory file for the child's answer; -1 on failure.
int makeAnswerFile() { return ::memfd_create("frostvdb-vdb-trial-answer", 0); }

/// The same trial in a freshly executed copy of this program (no inherited locks): the bytes go
/// through an in-memory file the new process reads before its main().
TrialResult trialParseInFreshProcess(const std::string& bytes)
{
    TrialResult t;
    const int inFd = ::memfd_create("frostvdb-vdb-trial", 0); // inherited across exec
    const int outFd = makeAnswerFile();
    if (inFd < 0 || outFd < 0 || !writeAll(inFd, bytes)) {
        if (inFd >= 0) ::close(inFd);
        if (outFd >= 0) ::close(outFd);
        t.reason = "the file could not be checked (no memory file for the check process)";
        return t;
    }
    const std::string fdText = std::to_string(inFd) + "," + std::to_string(outFd);
    const pid_t pid = ::fork();
    if (pid == 0) {
        ::setenv(kTrialFdVariable, fdText.c_str(), 1);
        char* const argv[] = {const_cast<char*>("frostvdb-vdb-trial"), nullptr};
        ::execv("/proc/self/exe", argv);
        ::_exit(5); // exec failed: reported as a failed check
    }
    ::close(inFd);
    if (pid < 0) {
        t.reason = "the file could not be checked (fork failed)";
    } else {
        t = awaitTrial(pid, outFd, /*detectStuck=*/false);
        if (t.stuck) t.reason = "the file could not be checked (the check process stalled)";
    }
    ::close(outFd);
    return t;
}

/// OpenVDB trusts the tree data inside a grid (node masks, compressed block sizes): a damaged
/// byte there can corrupt memory or ask for gigabytes. So the bytes are parsed in a child process
/// with a memory cap and a time limit, which takes that risk; this process parses only what the
/// child wrote back (see trialParseAndExit), never the file's own bytes.
TrialResult trialParseInChild(const std::string& bytes)
{
    const int outFd = makeAnswerFile();
    if (outFd < 0) return trialParseInFreshProcess(bytes);
    const pid_t pid = ::fork();
    if (pid == 0) trialParseAndExit(bytes, outFd);
    if (pid < 0) {
        ::close(outFd);
        return trialParseInFreshProcess(bytes);
    }
    // A hostile file makes the reader loop on the CPU: the child's CPU limit (30 s) stops it. A
    // child that sleeps instead is stuck on a lock some other thread of this process held at
    // fork() (a forked child inherits locks but not their owners): that says nothing about the
    // file, so the trial is repeated in a freshly executed process, which holds no such lock.
    TrialResult t = awaitTrial(pid, outFd, /*detectStuck=*/true);
    ::close(outFd);
    return t.stuck ? trialParseInFreshProcess(bytes) : t;
}

} // namespace

std::string checkVdbBytesInFreshProcess(const std::string& bytes)
{
    return trialParseInFreshProcess(bytes).reason;
}

openvdb::GridPtrVecPtr readVdb(const std::string& path, openvdb::MetaMap::Ptr* fileMeta, bool requireGrids)
{
    const std::string bytes = readWholeFile(path);
    noteInputFile(path);
    const VdbLayout layout = validateVdb(path, bytes);
    if (requireGrids && layout.gridCount == 0) throw VdbFileError(path, "the file holds no grids");
    const TrialResult trial = trialParseInChild(bytes);
    if (!trial.reason.empty()) throw VdbFileError(path, trial.reason);
    try {
        return parseGrids(trial.clean, fileMeta);
    } catch (const std::exception& e) {
        throw VdbFileError(path, std::string("damaged grid data (") + e.what() + ")");
    }
}

} // namespace frostvdb
