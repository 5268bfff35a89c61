#pragma once
/// @file VdbIO.h
/// @brief Output files for DCC tools: frame sequences `name.0001.vdb`, written through
/// AtomicFile (temporary, checked writes, fsync, rename), so a crash or a full disk never leaves
/// half a file under a frame name. Refuses to write non-finite values.
///
/// Input files are treated as hostile: the header, the metadata and every grid descriptor are
/// checked against the file length before OpenVDB allocates anything, and the grids are then
/// parsed from memory by a stream that stops at the first read past the end.
#include <openvdb/openvdb.h>
#include <openvdb/io/Compression.h>

#include <functional>

#include <stdexcept>
#include <string>
#include <vector>

namespace frostvdb {

/// "dir/name.0007.vdb"
std::string framePath(const std::string& dir, const std::string& name, int64_t frame,
                      const std::string& ext = "vdb");
/// A VDB input that cannot be read: one line, "<file>: not a readable VDB file (<reason>)".
class VdbFileError : public std::runtime_error {
public:
    VdbFileError(const std::string& path, const std::string& reason);
};

/// OpenVDB's own default when built with Blosc (as Debian's is): Blosc and the active mask.
constexpr uint32_t kDefaultVdbCompression = openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK;

/// "blosc", "zip" (each with the active mask) or "none" -> OpenVDB compression flags; throws
/// std::invalid_argument otherwise.
uint32_t compressionFlags(const std::string& name);
/// Compression flags -> "blosc + active mask", "zip + active mask", "none", ...
std::string compressionText(uint32_t flags);

/// One grid as its descriptor states it.
struct VdbGridSpan {
    std::string name, type;
    int64_t gridPos = 0, blockPos = 0, endPos = 0;
    bool half = false;        ///< stored as 16-bit halves (type name ends in _HalfFloat)
    int64_t compression = -1; ///< the grid's compression flags as stored, -1 when the file does not say
};
/// What validateVdb found.
struct VdbLayout {
    uint32_t fileVersion = 0;
    bool hasOffsets = false;
    int32_t gridCount = 0;
    std::vector<VdbGridSpan> grids;
};

/// The whole file's bytes; throws VdbFileError naming the OS reason.
std::string readWholeFile(const std::string& path);
/// Checks magic, version, metadata and grid descriptors against the byte count without
/// allocating more than the strings it reads; throws VdbFileError with the byte position.
VdbLayout validateVdb(const std::string& path, const std::string& bytes);

/// One line of at most @a maxChars characters: control characters replaced, the rest cut with "...".
std::string shortMessage(std::string s, size_t maxChars = 300);

/// Throws SimulationError naming the grid and voxel if any float/vector value is not finite (a
/// StreamedFloatGrid checks its values itself, as it writes them).
void checkFinite(const openvdb::GridBase& grid);

/// Writes grids and file metadata atomically. Each grid is checked finite first.
void writeVdbAtomic(const std::string& path, const openvdb::GridPtrVec& grids,
                    const openvdb::MetaMap& fileMeta, bool halfFloat = false,
                    uint32_t compression = kDefaultVdbCompression);

/// @a compression: OpenVDB stream flags for every grid (as Archive::setCompression; OpenVDB
/// itself drops zip for fog volumes and level sets, Blosc is kept).
/// Writes @a count grids atomically, asking @a next for them one at a time (index order), so
/// that only the grid being written need exist: a frame of a large domain is exported grid by
/// grid, each dropped once written. Same bytes as writeVdbAtomic (the header's random UUID
/// aside). Each grid is checked finite before it is written; any failure (a non-finite value,
/// a throwing @a next, a failed write) leaves the final name untouched. Names must be distinct.
void writeVdbStreamed(const std::string& path, size_t count,
                      const std::function<openvdb::GridBase::Ptr(size_t)>& next, const openvdb::MetaMap& fileMeta,
                      bool halfFloat = false, uint32_t compression = kDefaultVdbCompression);

/// Reads every grid of a file (and its file metadata, if @a fileMeta is given) after
/// validateVdb. @a requireGrids: a file without grids is an error. Throws VdbFileError.
openvdb::GridPtrVecPtr readVdb(const std::string& path, openvdb::MetaMap::Ptr* fileMeta = nullptr,
                               bool requireGrids = true);

/// The safety check readVdb runs on a file's bytes, in a freshly executed copy of this program
/// (readVdb uses it when a forked check stalls on a lock): "" when parsing @a bytes is safe,
/// else why not. Exposed for tests.
std::string checkVdbBytesInFreshProcess(const std::string& bytes);

/// Creates a directory and its parents.
void makeDirectories(const std::string& dir);

} // namespace frostvdb
