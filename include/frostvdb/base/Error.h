#pragma once
/// @file base/Error.h
/// @brief The two kinds of failure a user sees: bad input (SceneError) and a solver that left
/// its bounds (SimulationError). Both carry a one-line message that names where and why.
#include <stdexcept>
#include <string>

namespace frostvdb {

/// Bad input: a scene file, a --set override or a command-line value. The message reads
/// "FILE:LINE: KEY: what is wrong (allowed: ...)".
class SceneError : public std::runtime_error {
public:
    SceneError(const std::string& file, int line, const std::string& key, const std::string& what)
        : std::runtime_error(format(file, line, key, what)) {}
    explicit SceneError(const std::string& msg) : std::runtime_error(msg) {}

    static std::string format(const std::string& file, int line, const std::string& key,
                              const std::string& what)
    {
        std::string s = file.empty() ? std::string("<scene>") : file;
        if (line > 0) s += ":" + std::to_string(line);
        s += ": ";
        if (!key.empty()) s += key + ": ";
        return s + what;
    }
};

/// A simulation that went non-finite or out of bounds; names the field, voxel, step and time.
class SimulationError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

} // namespace frostvdb
