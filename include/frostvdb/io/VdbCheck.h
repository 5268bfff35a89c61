#pragma once
/// @file VdbCheck.h
/// @brief A cheap structural check of a .vdb file before OpenVDB reads it. OpenVDB's reader
/// allocates every length a file states (metadata names, types, values) before reading the bytes,
/// so a damaged 10 KB file can make it allocate gigabytes (found by fuzz/fuzz_vdb). This walks the
/// header, the file metadata, the grid descriptors and each grid's metadata and checks every
/// count and length against the bytes left in the file.
#include <string>

namespace frostvdb {

/// "" when the file's stated lengths are plausible (or its format is one this check does not
/// know, which it leaves to OpenVDB), else what is wrong, e.g. "metadata name of 1702194274
/// bytes at offset 9120, but the file has 10178".
std::string vdbLengthProblem(const std::string& path);

} // namespace frostvdb
