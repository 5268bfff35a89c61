#pragma once
/// @file FieldWriters.h
/// @brief How many effects of the scene declare that they write each field (from their
/// FieldDeclarations), published by the driver as World::state<FieldWriters>() before the
/// effects are initialised: an effect that is a field's only writer may skip checks for
/// changes made by others between its steps.
#include <map>
#include <string>

namespace frostvdb {

struct FieldWriters {
    std::map<std::string, int> count; ///< field name -> number of effects that write it

    int of(const std::string& field) const
    {
        auto it = count.find(field);
        return it == count.end() ? 0 : it->second;
    }
};

} // namespace frostvdb
