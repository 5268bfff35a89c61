#pragma once
// Tests that read a World's p or T by plane coordinates, or compare runs whose layouts may differ
// ([fluid] keeps the plane layout), read them in the plane layout: on a plane, p and T are folded
// (core/PlaneFold.h) and frames unfold them the same way.
#include <frostvdb/core/PlaneFold.h>

#include <openvdb/openvdb.h>

#include <string>

namespace frostvdb {
namespace test {

/// Field @a name of @a world in the plane layout (a copy; a grid not folded is copied as it is).
template <typename WorldT>
openvdb::FloatGrid::Ptr planeLayout(WorldT& world, const std::string& name)
{
    auto g = world.fields.template get<openvdb::FloatGrid>(name);
    return g ? plane::unfoldGrid(*g) : g;
}

} // namespace test
} // namespace frostvdb
