// The domain interface: kinds come from the registry, the support clips the active region, and a
// domain placed away from index 0 grows the same ice, bit for bit, shifted by its origin.
#include "test_util.h"
#include "plane_layout_util.h"

#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/icephysics/IceState.h>

#include <catch2/catch.hpp>

#include <algorithm>

using namespace frostvdb;
using namespace frostvdb::test;
using openvdb::Coord;

namespace {

/// A test domain: a disc of cells, to check that effects only see the support they are given.
/// @a centre: its middle cell (the bounds are the disc's box around it).
class DiscDomain : public DomainImpl {
public:
    explicit DiscDomain(int radius, const Coord& centre = Coord(0), std::string discretisation = "lattice")
        : DomainImpl(Lattice(), openvdb::CoordBBox(centre - Coord(radius, radius, 0), centre + Coord(radius, radius, 0)),
                     1e-4, false),
          mR(radius), mCentre(centre), mDiscretisation(std::move(discretisation)) {}
    std::string kind() const override { return "disc"; }
    std::string discretisation() const override { return mDiscretisation; }
    bool contains(const Coord& c) const override
    {
        const Coord o = c - mCentre;
        return mBounds.isInside(c) && o.x() * o.x() + o.y() * o.y() <= mR * mR;
    }
    void clipToSupport(openvdb::MaskTree& m) const override
    {
        DomainImpl::clipToSupport(m);
        std::vector<Coord> off;
        for (auto it = m.cbeginValueOn(); it; ++it)
            if (!contains(it.getCoord())) off.push_back(it.getCoord());
        for (const auto& c : off) m.setValueOff(c);
    }
    bool flat() const override { return true; }
    int intrinsicDimension() const override { return 2; }
    std::vector<Coord> walkerNeighbours() const override { return mLattice.planeNeighbours(); }
    int parameterDimension() const override { return 2; }
    openvdb::Vec3d parameterToIndex(const std::vector<double>& u) const override
    {
        return {mCentre.x() + (2 * u[0] - 1) * mR, mCentre.y() + (2 * u[1] - 1) * mR, 0};
    }
    std::vector<std::string> boundaryNames() const override { return {}; }
    void forEachBoundaryVoxel(const std::string&, int, const std::function<void(const Coord&)>&) const override {}

private:
    int mR;
    Coord mCentre;
    std::string mDiscretisation;
};

/// docs/architecture.md "Recipe: add a domain", step 2: the kind's reader (keys radius and
/// discretisation), registered for the scope of a test by DomainRegistrar below.
Domain readDisc(ParamDict& d, const DomainCommon&)
{
    const int r = int(d.getInt("radius", 20, 2, 1000, "cells", "radius of the disc"));
    const std::string disc = d.getString("discretisation", "lattice", {}, "the back ends to ask for");
    // the walkers' arrays index from the first cell: the disc's box starts at the origin
    return Domain(std::make_shared<DiscDomain>(r, Coord(r, r, 0), disc));
}

/// Registers the disc kind while in scope (the test binary's other tests list the built-in kinds).
struct ScopedDiscKind {
    ScopedDiscKind() { DomainRegistry::add({"disc", "a disc of cells (test)", readDisc}); }
    ~ScopedDiscKind() { DomainRegistry::remove("disc"); }
};

} // namespace

TEST_CASE("Domain kinds come from the registry and read their own keys", "[fast][domain]")
{
    std::vector<std::string> kinds;
    for (auto* k : DomainRegistry::all()) kinds.push_back(k->kind);
    for (const char* k : {"box", "plane", "shell"}) CHECK(std::find(kinds.begin(), kinds.end(), k) != kinds.end());

    auto plane = makeSim("[domain]\nsize = [40, 30]\norigin = [0.001, -0.002]\n[phase_field]\n").world().domain;
    CHECK(plane.kind() == "plane");
    CHECK(plane.flat());
    CHECK(plane.bbox() == openvdb::CoordBBox(Coord(10, -20, 0), Coord(49, 9, 0)));
    CHECK(plane.hasFrame());
    CHECK(plane.frame(Coord(12, 0, 0)).normal == openvdb::Vec3d(0, 0, 1));

    auto box = makeSim("[domain]\nkind = \"box\"\nsize = [8, 9, 10]\norigin = [0, 0, 0.0005]\n[phase_field]\n").world().domain;
    CHECK(box.kind() == "box");
    CHECK(!box.flat());
    CHECK(box.bbox() == openvdb::CoordBBox(Coord(0, 0, 5), Coord(7, 8, 14)));
    CHECK(!box.hasFrame());
    CHECK(box.walkerNeighbours().size() == 6);

    const auto msg = errorOf("[domain]\nkind = \"torus\"\n[phase_field]\n");
    CHECK(msg.find("domain.kind") != std::string::npos);
    CHECK(msg.find("box") != std::string::npos);
    CHECK(msg.find("plane") != std::string::npos);
}

TEST_CASE("Adding a domain kind changes no effect: the phase field and the walkers run on a registered disc",
          "[fast][domain]")
{
    ScopedDiscKind disc;
    auto sim = makeSim("[scene]\nframes = 1\nsteps_per_frame = 30\n[domain]\nkind = \"disc\"\nradius = 24\n"
                       "[[crystal.seed]]\nshape = \"point\"\nposition = [0.5, 0.5]\nradius = 3\n"
                       "[dla]\nhumidity = 40\n[phase_field]\nlatent_heat = 1.2\n");
    sim.initialize();
    CHECK(sim.world().domain.kind() == "disc");
    const auto& dom = sim.world().domain;
    auto count = [&](bool inside) {
        size_t n = 0;
        auto p = planeLayout(sim.world(), "p");
        REQUIRE(p);
        for (auto it = p->cbeginValueOn(); it; ++it)
            if (*it > 0.5f && dom.contains(it.getCoord()) == inside) ++n;
        return n;
    };
    const size_t seeded = count(true);
    for (int s = 0; s < 30; ++s) sim.step();
    CHECK(count(true) > seeded + 20); // both effects grew ice on it
    CHECK(count(false) == 0);         // and only on its support

    // a kind with numerics of its own needs its back ends: without them, one line naming the key
    const std::string msg = errorOf("[domain]\nkind = \"disc\"\ndiscretisation = \"spectral\"\n[phase_field]\n");
    CHECK(msg.find("domain.kind") != std::string::npos);
    CHECK(msg.find("spectral") != std::string::npos);
    const std::string walkers = errorOf("[domain]\nkind = \"disc\"\ndiscretisation = \"spectral\"\n[dla]\n");
    CHECK(walkers.find("domain.kind") != std::string::npos);
}

TEST_CASE("The active region is clipped to the domain's support, not to its bounds", "[fast][domain]")
{
    const Domain disc(std::make_shared<DiscDomain>(20));
    auto p = openvdb::FloatGrid::create(0.f);
    p->tree().setValue(Coord(18, 0, 0), 1.f); // near the rim: the dilation reaches past it
    RegionSettings rs;
    rs.frontTravel = 4;
    auto region = buildActiveRegion({p.get()}, rs, 1, disc);
    REQUIRE(region->activeVoxelCount() > 0);
    size_t outside = 0;
    for (auto it = region->cbeginValueOn(); it; ++it) outside += disc.contains(it.getCoord()) ? 0 : 1;
    CHECK(outside == 0);
    CHECK(region->tree().isValueOn(Coord(20, 0, 0)));
    CHECK(!region->tree().isValueOn(Coord(20, 3, 0))); // in the bounds, outside the disc

    rs.dense = true;
    auto dense = buildActiveRegion({p.get()}, rs, 1, disc);
    CHECK(dense->activeVoxelCount() == disc.bbox().volume()); // dense fills the (default) support: bounds
}

TEST_CASE("A plane placed away from index 0 grows the same ice, shifted", "[fast][domain]")
{
    // dla refuses an origin (dense walker arrays) until the sparse walkers land: run without it
    const std::string noDla = "[scene]\nseed = 3\n[region]\ntolerance = 0\n[phase_field]\n[fluid]\n"; // noise is keyed by the cell index
    auto runNoDla = [&](const std::string& domain) {
        auto sim = makeSim("[domain]\nsize = [40, 36]\nvoxel_size = 0.001\n" + domain + "\n" + noDla +
                           "[crystal]\n[[crystal.seed]]\nposition = [0.4, 0.5]\n");
        for (int i = 0; i < 30; ++i) sim.step();
        return std::make_pair(sim.world().fields.get<openvdb::FloatGrid>(ice::kPhase),
                              sim.world().fields.get<openvdb::FloatGrid>(ice::kTemperature));
    };
    const Coord shift(-37, 21, 0); // a plane keeps index z = 0; its height is in the transform
    auto [p0, t0] = runNoDla("");
    auto [p1, t1] = runNoDla("origin = [-0.037, 0.021, 0.005]");
    REQUIRE(p0->activeVoxelCount() > 20);
    CHECK(p1->transform().indexToWorld(Coord(-37, 21, 0)).z() == Approx(0.005));
    CHECK(p1->transform().indexToWorld(Coord(-37, 21, 0)).x() == Approx(-0.037));
    CHECK(p0->activeVoxelCount() == p1->activeVoxelCount());
    CHECK(t0->activeVoxelCount() == t1->activeVoxelCount());
    size_t differ = 0;
    auto a1 = p1->getConstAccessor();
    auto b1 = t1->getConstAccessor();
    for (auto it = p0->cbeginValueOn(); it; ++it) differ += a1.getValue(it.getCoord() + shift) != *it;
    for (auto it = t0->cbeginValueOn(); it; ++it) differ += b1.getValue(it.getCoord() + shift) != *it;
    CHECK(differ == 0);

    const auto msg = errorOf("[domain]\nsize = [40, 36]\nvoxel_size = 0.001\norigin = [0.01, 0]\n[dla]\n");
    CHECK(msg.find("domain.origin") != std::string::npos);
}

TEST_CASE("Seeds are placed in world metres or in the domain's fractions alike", "[fast][domain]")
{
    const std::string base = "[domain]\nsize = [40, 40]\nvoxel_size = 0.001\norigin = [0.1, 0.2]\n[phase_field]\n";
    auto frac = makeSim(base + "[crystal]\n[[crystal.seed]]\nposition = [0.25, 0.5]\nradius = 3\n");
    auto world = makeSim(base + "[crystal]\n[[crystal.seed]]\nspace = \"world\"\nposition = [0.10975, 0.2195]\nradius = 3\n");
    frac.initialize();
    world.initialize();
    auto pf = frac.world().fields.get<openvdb::FloatGrid>(ice::kPhase);
    auto pw = world.world().fields.get<openvdb::FloatGrid>(ice::kPhase);
    REQUIRE(pf->activeVoxelCount() > 20);
    CHECK(maxAbsDiff(*pf, *pw) == 0.0);
    CHECK(pf->tree().getValue(Coord(109, 219, 0)) == 1.f); // 0.25 * 39 = 9.75 cells from x0 = 100
}
