#pragma once
/// @file ShellDomain.h
/// @brief `[domain] kind = "shell"`: a narrow band around a mesh (src/core/domains/ShellDomain.cpp).
/// Effects that run surface operators get the band from the domain here; every other effect sees
/// the plain Domain interface (support = the band, frame = the smooth tangent frame at cp).
#include <frostvdb/core/Domain.h>
#include <frostvdb/shell/ShellBand.h>

#include <memory>

namespace frostvdb::shell {

/// The band of a shell domain, or null when @a domain has none.
std::shared_ptr<const ShellBand> bandOf(const Domain& domain);

/// A shell domain around @a mesh (world metres). @a spacing: the PDE spacing h.
Domain makeShellDomain(const TriangleMesh& mesh, const BandSettings& settings, double spacing);

} // namespace frostvdb::shell
