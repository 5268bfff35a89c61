#pragma once
/// @file ShellDla.h
/// @brief `[dla]` on a shell domain: the plane's keys and semantics (humidity H and its schedule,
/// hits n, heat_release L, melt map as sticking probability, max_steps, jumps, batch,
/// flow_drift) with walkers on the surface (shell/ShellWalkers.h). release = "uniform" picks
/// surface points uniformly by area, "perimeter" the open mesh's border. Steam humidity is not
/// available on shells. The drift is the tangential wind of `[phase_field]` (ShellWindState).
/// Runs at the Walkers stage, before the phase field (the driver's order). Walkers roam the whole
/// surface, so makeShellDla builds the (lazy) band whole when the scene is read.
#include <frostvdb/core/Effect.h>
#include <frostvdb/ice/Dla.h>

#include <memory>

namespace frostvdb::shell {

/// The [dla] effect on a shell domain (DlaEffect::create hands over to it on shells).
std::unique_ptr<Effect> makeShellDla(const ice::DlaParams& params, ParamDict& d, const World& world);

} // namespace frostvdb::shell
