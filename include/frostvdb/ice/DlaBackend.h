#pragma once
/// @file DlaBackend.h
/// @brief The walkers [dla] runs, chosen by the domain. DlaEffect::create reads the keys every
/// discretisation shares (ice::DlaParams) and hands them to the back end registered under
/// `Domain::discretisation()`; the back end is the effect that walks (it checks its own
/// preconditions and refuses with the key at fault). Built in: `"lattice"` (planes and boxes:
/// ice::DlaEffect on DlaEngine, src/ice/DlaEffect.cpp) and `"surface"`/`"closest_point"`
/// (shells: walkers on the surface, src/shell/ShellDlaEffect.cpp).
#include <frostvdb/core/Effect.h>
#include <frostvdb/ice/Dla.h>

#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace frostvdb::ice {

using DlaBackendFactory = std::function<std::unique_ptr<Effect>(const DlaParams&, ParamDict&, const World&)>;

class DlaBackends {
public:
    static void add(const std::vector<std::string>& discretisations, DlaBackendFactory make);
    /// The factory serving @a discretisation, or null.
    static const DlaBackendFactory* find(const std::string& discretisation);
};

struct DlaBackendRegistrar {
    DlaBackendRegistrar(const std::vector<std::string>& discretisations, DlaBackendFactory make)
    { DlaBackends::add(discretisations, std::move(make)); }
};

} // namespace frostvdb::ice

#define FROSTVDB_REGISTER_DLA_BACKEND(ID, DISCRETISATIONS, FACTORY) \
    static ::frostvdb::ice::DlaBackendRegistrar frostvdbDlaBackend_##ID(DISCRETISATIONS, FACTORY)
