#pragma once
/// @file FieldEdits.h
/// @brief Point writes reported between steps: an effect that writes single cells of a field
/// another effect keeps state about (DLA walkers freezing cells of p and T, which the phase
/// field's active region covers) lists the cells it changed, so the keeper can update its state
/// around them instead of re-reading the whole field. Published as World::state<FieldEdits>().
///
/// Protocol: a writer calls reports(field, this) in initialize and appends every cell it changes
/// to sink(field) (null while nobody listens); a keeper calls listen(field) once (initialize),
/// reads cells(field) before its step and clears it after. The keeper may trust the list only
/// when every other writer of the field reports (FieldWriters::of(field) - 1 == reporters).
#include <openvdb/openvdb.h>

#include <map>
#include <set>
#include <string>
#include <vector>

namespace frostvdb {

struct FieldEdits {
    struct Log {
        std::set<const void*> reporters; ///< effects that list every cell they write
        bool listened = false;
        std::vector<openvdb::Coord> cells; ///< written since the keeper last cleared (may repeat)
    };
    std::map<std::string, Log> logs;

    /// @a who: the reporting effect (an effect initialised twice still counts once).
    void reports(const std::string& field, const void* who) { logs[field].reporters.insert(who); }
    void listen(const std::string& field) { logs[field].listened = true; }
    bool listened(const std::string& field) const
    {
        auto it = logs.find(field);
        return it != logs.end() && it->second.listened;
    }
    int reporters(const std::string& field) const
    {
        auto it = logs.find(field);
        return it == logs.end() ? 0 : int(it->second.reporters.size());
    }
    /// The log a writer appends to, or null when nobody listens (nothing is kept then).
    std::vector<openvdb::Coord>* sink(const std::string& field)
    {
        auto it = logs.find(field);
        return it != logs.end() && it->second.listened ? &it->second.cells : nullptr;
    }
    std::vector<openvdb::Coord>& cells(const std::string& field) { return logs[field].cells; }

    /// Crossings of 1/2 (the ice threshold of p): the cells whose value went from above 1/2 to at
    /// most 1/2 or back, reported by writers that change a field a step at a time (the phase
    /// field), so that a keeper of "where is the ice" (the walkers' distance map) reads those cells
    /// instead of the whole field. Same protocol as the point writes above, in its own logs: the
    /// keeper trusts them only when every other writer of the field reports its crossings.
    std::map<std::string, Log> crossings;
    void reportsCrossings(const std::string& field, const void* who) { crossings[field].reporters.insert(who); }
    void listenCrossings(const std::string& field) { crossings[field].listened = true; }
    int crossingReporters(const std::string& field) const
    {
        auto it = crossings.find(field);
        return it == crossings.end() ? 0 : int(it->second.reporters.size());
    }
    std::vector<openvdb::Coord>* crossingSink(const std::string& field)
    {
        auto it = crossings.find(field);
        return it != crossings.end() && it->second.listened ? &it->second.cells : nullptr;
    }
    std::vector<openvdb::Coord>& crossingCells(const std::string& field) { return crossings[field].cells; }
};

} // namespace frostvdb
