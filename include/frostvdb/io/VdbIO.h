#pragma once
/// @file VdbIO.h
/// @brief Output files for DCC tools: frame sequences `name.0001.vdb`, written to a temporary
/// name in the same folder and renamed, so a crash never leaves half a file and an existing
/// file is only ever replaced by a complete one. Refuses to write non-finite values.
#include <openvdb/openvdb.h>

#include <string>

namespace frostvdb {

/// "dir/name.0007.vdb"
std::string framePath(const std::string& dir, const std::string& name, int64_t frame,
                      const std::string& ext = "vdb");
/// A unique temporary path beside @a path.
std::string temporaryPathFor(const std::string& path);
/// Renames a finished temporary file onto its final path (atomic on one file system).
void commitTemporary(const std::string& tmp, const std::string& path);

/// Throws SimulationError naming the grid and voxel if any float/vector value is not finite.
void checkFinite(const openvdb::GridBase& grid);

/// Writes grids and file metadata atomically. Each grid is checked finite first.
void writeVdbAtomic(const std::string& path, const openvdb::GridPtrVec& grids,
                    const openvdb::MetaMap& fileMeta, bool halfFloat = false);

/// Reads every grid of a file (and its file metadata, if @a fileMeta is given).
openvdb::GridPtrVecPtr readVdb(const std::string& path, openvdb::MetaMap::Ptr* fileMeta = nullptr);

/// Creates a directory and its parents.
void makeDirectories(const std::string& dir);

} // namespace frostvdb
