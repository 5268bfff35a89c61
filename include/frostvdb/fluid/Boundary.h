#pragma once
/// @file Boundary.h
/// @brief The one boundary vocabulary of [fluid]'s two solvers (the dense MAC grid of
/// fluid/Fluid.h and the sparse band of fluid/SparseFluid.h): what a domain side is, and how the
/// inflow speed varies across the inflow side.
#include <cstdint>

namespace frostvdb {
namespace fluid {

/// A domain side: outflow (zero-gradient velocity, p = 0), a free-slip solid wall, or the inflow.
enum class SideKind : uint8_t { Outflow, Wall, Inflow };

/// Inflow speed across the inflow side, s in [0, 1] along it: uniform U, linear s U, quadratic
/// s^2 U (the ice paper's ramp, Figure 6), parabolic 4 s (1 - s) U (Figure 10).
enum class Profile : uint8_t { Uniform, Linear, Quadratic, Parabolic };

} // namespace fluid
} // namespace frostvdb
