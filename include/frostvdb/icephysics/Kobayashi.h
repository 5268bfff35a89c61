#pragma once
/// @file Kobayashi.h
/// @brief The Kobayashi phase-field model of the ice paper (Kim, Henson & Lin 2004, eqs. 1-5):
///
///   tau dp/dt = div(eps^2 grad p) - d/dx(eps eps' dp/dy) + d/dy(eps eps' dp/dx) + n(p, T)
///   dT/dt     = lap T + K dp/dt
///   eps(theta) = eps_bar (1 + delta cos(j (theta0 - theta))),  theta = atan2(p_y, p_x)
///   n(p, T)    = p (1 - p) (p - 1/2 + m(T) + a chi),  m(T) = alpha/pi atan(gamma (T_e - T))
///
/// (a chi is Kobayashi's optional noise, chi uniform in [-1/2, 1/2], off by default.)
///
/// Two schemes:
///  - Euler: the full equations 1-2, forward Euler (the paper's dt 0.0002);
///  - second order (section 5): the simplified equation 8,
///      tau dp/dt = grad(eps^2) . grad p + eps^2 lap p + n(p, T),
///    with Lax-Wendroff on the advection term, Crank-Nicolson on the diffusion term and on
///    lap T, and the reaction linearised about p^n and split trapezoidally (n + n'/2 (p' - p)),
///    so that its stiff decay at p = 0 and 1 does not limit dt (the paper's dt 0.0008 exceeds
///    2 tau / |n'| where T is warm). The implicit systems are solved by ImplicitSystem.
/// The melt map (field `melt`, 1 where absent) scales the undercooling locally:
///   T_e(x) = T_inf + melt(x) (T_e - T_inf).
///
/// The per-cell arithmetic lives here as inline functions over flat arrays with precomputed
/// neighbour offsets, so the sparse VDB kernel (per leaf, on a padded block) and the plain
/// dense-array reference loop run literally the same code.
#include <frostvdb/core/Lattice.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>

namespace frostvdb {

enum class PhaseFieldScheme { Euler, SecondOrder };

struct KobayashiParams {
    double tau = 0.0003;
    double epsBar = 0.01;
    double delta = 0.1;
    double anisotropyMode = 6.0; ///< j
    double theta0 = M_PI / 2.0;
    double alpha = 0.9;
    double gamma = 10.0;
    double meltTemperature = 1.0; ///< T_e
    double latentHeat = 1.5;      ///< K
    double farTemperature = 0.0;  ///< T_inf: initial and far-field temperature
    double noise = 0.0;           ///< a
    double dt = 0.0002;
    PhaseFieldScheme scheme = PhaseFieldScheme::Euler;
    double solverTolerance = 1e-8; ///< max-norm residual of the implicit systems (second order)
    int solverMaxIterations = 500;
    bool useBiCGSTAB = false;      ///< second order: Eigen BiCGSTAB instead of Gauss-Seidel

    /// T_e at a voxel with melt-map value @a melt.
    double localMeltTemperature(double melt) const
    {
        return farTemperature + melt * (meltTemperature - farTemperature);
    }

    /// Bounds of the reaction's slope dn/dp over p in [0,1] and every m(T) in (-alpha/2, alpha/2)
    /// (plus the noise): the largest growth rate (dn/dp > 0, inside the interface) and the
    /// largest decay rate |dn/dp| (at p = 0 and 1). Sampled finely; n is a cubic in p.
    void reactionSlopeBounds(double& maxGrowth, double& maxDecay) const
    {
        maxGrowth = 0;
        maxDecay = 0;
        const double mMax = 0.5 * std::fabs(alpha) + 0.5 * std::fabs(noise);
        for (double m : {-mMax, 0.0, mMax})
            for (int q = 0; q <= 1000; ++q) {
                const double pp = q / 1000.0, g = pp - 0.5 + m;
                const double dn = (1.0 - 2.0 * pp) * g + pp * (1.0 - pp);
                maxGrowth = std::fmax(maxGrowth, dn);
                maxDecay = std::fmax(maxDecay, -dn);
            }
    }

    /// Largest forward-Euler dt that keeps the update monotone, so p stays within [0, 1] and T
    /// within its sources' bounds: every coefficient of the explicit update stays >= 0, i.e.
    /// dt (eps_max^2 |w0| + max|dn/dp|) <= tau for the phase and dt |w0| <= 1 for the heat
    /// (w0 the Laplacian's centre weight). Taking the terms one by one (diffusion alone, then
    /// reaction alone) is not enough: the stability suite saw p reach 1.016 at that dt.
    double explicitStabilityLimit(const Stencil& s) const
    {
        const double w0 = std::fabs(s.wLapCentre);
        const double epsMax = epsBar * (1.0 + std::fabs(delta));
        double growth, decay;
        reactionSlopeBounds(growth, decay);
        return std::fmin(1.0 / w0, tau / (epsMax * epsMax * w0 + std::fmax(growth, decay)));
    }

    /// Largest dt at which the second-order step keeps p and T within their bounds. Its
    /// implicit side is an M-matrix at any dt; what limits dt is the explicit (1 - theta) half,
    /// theta = 1/2, whose coefficients must stay >= 0 (a positive combination of old values):
    ///  - heat: dt/2 |w0| <= 1 (w0 the Laplacian's centre weight);
    ///  - phase: dt/(2 tau) sum_q C_q <= 1, sum_q C_q = a_eff |w0| <= eps_max^2 |w0| (the raised
    ///    a_eff of a Peclet-limited tap stays below (eps_max^2 - eps_min^2)/3);
    ///  - the growing reaction inside the interface, whose trapezoidal factor (1 + r n'/2) /
    ///    (1 - r n'/2), r = dt/tau, would overshoot p's bounds once r n' > 1: dt <= tau / max n'.
    /// The decaying reaction (|n'| up to 1/2 + alpha/2 where the melt is warmer than T_e) is not
    /// in the limit: trapezoidal decay stays bounded by the old value (A-stable) and only dips
    /// below 0 by a fraction of an already small p where r |n'| / 2 > 1 (melting cells).
    /// The advection needs no CFL condition: it is inside the implicit Crank-Nicolson average.
    double secondOrderStabilityLimit(const Stencil& s, bool /*withZ*/) const
    {
        const double w0 = std::fabs(s.wLapCentre);
        const double epsMax = epsBar * (1.0 + std::fabs(delta));
        double limit = std::fmin(2.0 / w0, 2.0 * tau / (epsMax * epsMax * w0));
        double growth, decay;
        reactionSlopeBounds(growth, decay);
        if (growth > 0) limit = std::fmin(limit, tau / growth);
        return limit;
    }

    double stabilityLimit(const Stencil& s, bool withZ) const
    {
        return scheme == PhaseFieldScheme::Euler ? explicitStabilityLimit(s) : secondOrderStabilityLimit(s, withZ);
    }
};

/// Gradient (change of p per cell) below which the second-order scheme fades the anisotropy
/// out (kobayashiEpsSquared).
constexpr double kFlatGradientPerCell = 0.005;

/// A stencil flattened for one array layout: neighbour k of cell i is at i + off[k].
struct FlatStencil {
    static constexpr int kMaxTaps = 8;
    int n = 0;
    std::ptrdiff_t off[kMaxTaps];
    double ex[kMaxTaps], ey[kMaxTaps], ez[kMaxTaps], wGrad[kMaxTaps], wLap[kMaxTaps];
    double invH2 = 1;       ///< 1/h^2: weight of a directional second difference
    bool hexagonal = false; ///< in-plane taps are the 3 hexagonal directions
    double wLapSum = 0;     ///< -(centre weight of the Laplacian)
    double flatGradient2 = 0; ///< sigma^2 of kobayashiEpsSquared: (kFlatGradientPerCell / h)^2
    /// e_{2k} . e_{2l} for the opposite-tap pairs k, l (taps come as +e, -e), rounded to the
    /// exact multiple of 1/2 it is on the square and hexagonal lattices.
    double pairDot[kMaxTaps / 2][kMaxTaps / 2] = {};
    /// Forward Euler evaluates eq. 1 by the D6-invariant hexagonal forms (kobayashiAux): set by
    /// useD6Forms() for the hexagonal plane with j = 6 and arms on lattice directions.
    bool d6 = false;

    /// @a strideY, @a strideZ: distance between rows and slices of the layout.
    FlatStencil(const Stencil& s, std::ptrdiff_t strideY, std::ptrdiff_t strideZ)
    {
        for (const auto& t : s.taps) {
            off[n] = t.offset.x() + t.offset.y() * strideY + t.offset.z() * strideZ;
            ex[n] = t.ex;
            ey[n] = t.ey;
            ez[n] = t.ez;
            wGrad[n] = t.wGrad;
            wLap[n] = t.wLap;
            ++n;
        }
        invH2 = 1.0 / (s.spacing * s.spacing);
        hexagonal = s.hexagonal;
        wLapSum = -s.wLapCentre;
        flatGradient2 = (kFlatGradientPerCell / s.spacing) * (kFlatGradientPerCell / s.spacing);
        for (int k = 0; 2 * k < n; ++k)
            for (int l = 0; 2 * l < n; ++l) {
                const double d = ex[2 * k] * ex[2 * l] + ey[2 * k] * ey[2 * l] + ez[2 * k] * ez[2 * l];
                pairDot[k][l] = std::round(2.0 * d) / 2.0;
            }
    }
};

/// Precomputed per-run constants of the anisotropy.
struct Anisotropy {
    double epsBar, delta, j, theta0, cj0, sj0;
    int integerMode; ///< j as an integer >= 0, or -1 when j is fractional
    explicit Anisotropy(const KobayashiParams& k)
        : epsBar(k.epsBar), delta(k.delta), j(k.anisotropyMode), theta0(k.theta0),
          cj0(snap(std::cos(k.anisotropyMode * k.theta0))), sj0(snap(std::sin(k.anisotropyMode * k.theta0))),
          integerMode(std::floor(k.anisotropyMode) == k.anisotropyMode ? int(k.anisotropyMode) : -1)
    {
    }
    /// cos/sin of j theta0 within rounding of 0 or +-1 are those exactly (sin(6 pi/2) is 4e-16,
    /// not 0, and would tilt the arms off the lattice's mirror axes by that much).
    static double snap(double v)
    {
        for (double e : {-1.0, 0.0, 1.0})
            if (std::fabs(v - e) < 1e-12) return e;
        return v;
    }

    /// eps(theta) and d eps / d theta for the gradient direction (gx, gy). Integer j avoids
    /// trigonometry: e^{i j theta} is the j-th power of the unit gradient as a complex number.
    inline void operator()(double gx, double gy, double& eps, double& epsPrime) const
    {
        double c, s; // cos and sin of j (theta0 - theta)
        if (integerMode >= 0) {
            double wr = 1.0, wi = 0.0;
            const double r2 = gx * gx + gy * gy;
            if (r2 > 1e-30) {
                const double inv = 1.0 / std::sqrt(r2);
                const double zr = gx * inv, zi = gy * inv;
                for (int q = 0; q < integerMode; ++q) {
                    const double t = wr * zr - wi * zi;
                    wi = wr * zi + wi * zr;
                    wr = t;
                }
            }
            c = cj0 * wr + sj0 * wi;
            s = sj0 * wr - cj0 * wi;
        } else {
            const double theta = std::atan2(gy, gx);
            c = std::cos(j * (theta0 - theta));
            s = std::sin(j * (theta0 - theta));
        }
        eps = epsBar * (1.0 + delta * c);
        epsPrime = epsBar * delta * j * s;
    }
};

/// Sum of up to kMaxTaps values in an order fixed by the values alone (ascending), so that a
/// cell and its rotated or mirrored image, whose terms are the same values in another order,
/// get bit-identical sums. Only for terms that symmetries permute without changing their sign
/// (scalar fields: products of weights and values, squares).
inline double canonicalSum(double* v, int n)
{
    // 2 and 3 terms (the plane's pair sums): min/max networks, the same sorted values and
    // additions without data-dependent branches (mispredicted swaps cost more than the sums)
    if (n == 3) {
        const double a = std::min(v[0], v[1]), b = std::max(v[0], v[1]);
        const double lo = std::min(a, v[2]), t = std::max(a, v[2]);
        return ((0.0 + lo) + std::min(b, t)) + std::max(b, t);
    }
    if (n == 2) return (0.0 + std::min(v[0], v[1])) + std::max(v[0], v[1]);
    for (int a = 1; a < n; ++a)
        for (int b = a; b > 0 && v[b] < v[b - 1]; --b) std::swap(v[b], v[b - 1]);
    double s = 0;
    for (int a = 0; a < n; ++a) s += v[a];
    return s;
}

/// sum_q w_q (u_q - u_i) over opposite-tap pairs, the pair sums in canonical order.
inline double symmetricTapSum(const float* u, std::size_t i, const FlatStencil& st, const double* w)
{
    const double u0 = u[i];
    double pair[FlatStencil::kMaxTaps / 2];
    const int np = st.n / 2;
    for (int k = 0; k < np; ++k)
        pair[k] = w[2 * k] * (double(u[i + st.off[2 * k]]) - u0) + w[2 * k + 1] * (double(u[i + st.off[2 * k + 1]]) - u0);
    return canonicalSum(pair, np);
}

/// Enables the D6-invariant forms of forward Euler where the lattice allows them: the hexagonal
/// plane (6 taps) with an integer mode j = 6 and sin(j theta0) = 0 (arms on lattice directions).
inline void useD6Forms(FlatStencil& st, const Anisotropy& an)
{
    st.d6 = st.hexagonal && st.n == 6 && an.integerMode == 6 && an.sj0 == 0.0;
}

/// Product of three values in an order fixed by their magnitudes, so that values a symmetry
/// permutes and negates give the same bits up to the sign.
inline double canonicalProduct3(double a, double b, double c)
{
    double v[3] = {a, b, c};
    for (int x = 1; x < 3; ++x)
        for (int y = x; y > 0 && std::fabs(v[y]) < std::fabs(v[y - 1]); --y) std::swap(v[y], v[y - 1]);
    return (v[0] * v[1]) * v[2];
}

/// Hexagonal plane: the central gradient of @a u at cell i projected on the three lattice
/// directions (0, 60, -60 degrees; taps 0/1, 2/3, 4/5), in units of wGrad: g . e_k = wGrad U[k].
/// From the pair differences D_k alone (exact weights 1 and 1/2), so that a 60-degree rotation
/// or a mirror of the field permutes and negates the U[k] bit for bit.
inline void hexProjections(const float* u, std::size_t i, const FlatStencil& st, double U[3])
{
    double D[3];
    for (int k = 0; k < 3; ++k) D[k] = double(u[i + st.off[2 * k]]) - double(u[i + st.off[2 * k + 1]]);
    U[0] = D[0] + (0.5 * D[1] + 0.5 * D[2]);
    U[1] = D[1] + (0.5 * D[0] - 0.5 * D[2]);
    U[2] = D[2] + (0.5 * D[0] - 0.5 * D[1]);
}

/// eps and eps' (Anisotropy's convention) from the projections U of the gradient, j = 6, by
/// functions that rotations leave bit-identical and mirrors negate exactly (eps' is odd):
/// with n_k = U_k / |U| (|U|^2 = sum U_k^2),
///   cos 6 theta = 108 (n0 n1 n2)^2 - 1,
///   sin 6 theta = 2 cos 3 theta sin 3 theta = 12 sqrt(3) (n0 n1 n2) ((n1 - n2)(n0 + n2)(n0 + n1)),
/// (the second triple are the projections on the directions at 90, -30 and 30 degrees, times
/// sqrt 3). theta is 0 where there is no gradient, as in Anisotropy.
inline void hexEpsilonD6(const double U[3], const FlatStencil& st, const Anisotropy& an, double& eps,
                         double& epsPrime)
{
    double sq[3] = {U[0] * U[0], U[1] * U[1], U[2] * U[2]};
    for (int x = 1; x < 3; ++x)
        for (int y = x; y > 0 && sq[y] < sq[y - 1]; --y) std::swap(sq[y], sq[y - 1]);
    const double S = (sq[0] + sq[1]) + sq[2];
    double c6 = 1.0, s6 = 0.0;
    if ((2.0 / 3.0) * (st.wGrad[0] * st.wGrad[0]) * S > 1e-30) {
        const double inv = 1.0 / std::sqrt(S);
        const double n0 = U[0] * inv, n1 = U[1] * inv, n2 = U[2] * inv;
        const double P = canonicalProduct3(n0, n1, n2);
        const double Q = canonicalProduct3(n1 - n2, n0 + n2, n0 + n1);
        c6 = 108.0 * (P * P) - 1.0;
        s6 = (12.0 * std::sqrt(3.0) * P) * Q;
    }
    eps = an.epsBar * (1.0 + an.delta * (an.cj0 * c6));
    epsPrime = an.epsBar * an.delta * 6.0 * -(an.cj0 * s6);
}

/// Laplacian sum_q w_q (u_q - u_i): in tap order, or on the hexagonal plane in canonical pair
/// order (symmetricTapSum), so that rotated images get the same bits.
inline double eulerLaplacian(const float* u, std::size_t i, const FlatStencil& st)
{
    if (st.hexagonal && st.n == 6) return symmetricTapSum(u, i, st, st.wLap);
    const double u0 = u[i];
    double s = 0;
    for (int q = 0; q < st.n; ++q) s += st.wLap[q] * (double(u[i + st.off[q]]) - u0);
    return s;
}

/// Pass 1 at cell i: the gradient of p and the anisotropic coefficients the update needs at
/// the neighbours: a = eps^2, cx = eps eps' p_x, cy = eps eps' p_y.
inline void kobayashiAux(const float* p, std::size_t i, const FlatStencil& st, const Anisotropy& an,
                         float* a, float* cx, float* cy, float* gx, float* gy, float* gz)
{
    if (st.d6) {
        // D6 forms: a = eps^2 and b = eps eps' (in cx); pass 2 takes the gradients itself.
        double U[3], eps, epsPrime;
        hexProjections(p, i, st, U);
        hexEpsilonD6(U, st, an, eps, epsPrime);
        a[i] = float(eps * eps);
        cx[i] = float(eps * epsPrime);
        return;
    }
    const double p0 = p[i];
    double sx = 0, sy = 0, sz = 0;
    for (int q = 0; q < st.n; ++q) {
        const double d = st.wGrad[q] * (double(p[i + st.off[q]]) - p0);
        sx += d * st.ex[q];
        sy += d * st.ey[q];
        sz += d * st.ez[q];
    }
    double eps, epsPrime;
    an(sx, sy, eps, epsPrime);
    a[i] = float(eps * eps);
    cx[i] = float(eps * epsPrime * sx);
    cy[i] = float(eps * epsPrime * sy);
    gx[i] = float(sx);
    gy[i] = float(sy);
    gz[i] = float(sz);
}

/// Pass 2 at cell i: forward-Euler update of p and T (eqs. 1-2). @a Te is the local melt
/// temperature, @a chi the noise draw in [-1/2, 1/2] (ignored when noise is 0). Returns dp.
///
/// Bounded: the update splits into a monotone part, eps^2 lap p + n(p, T) (positive weights, and
/// below explicitStabilityLimit a convex combination of the neighbourhood plus the reaction), and
/// the anisotropic rest, grad(eps^2) . grad p plus the cross terms of eq. 1, whose central
/// differences have weights of either sign: at a sharp seed they pushed p to -0.012 next to the
/// seed (delta 0.2, square). The rest is limited so that it creates no new extremum: the new p
/// stays within the range of p over the cell and its taps, widened to include the monotone
/// update itself (the reaction may grow a cell past its neighbours). Where the fields are smooth
/// the limiter is inactive (a convex combination stays inside its neighbours' range); at an
/// extremum it keeps the monotone part. With p in [0, 1] and dt below the limit, p stays in [0, 1].
///
/// On the hexagonal plane with j = 6 (st.d6) every term is a D6-invariant form of the pair
/// differences, summed in canonical order, so rotated and mirrored cells get the same bits:
///   grad a . grad p = 2/3 wGrad^2 sum_k U_k(a) U_k(p),
///   cross terms     = grad p x grad b (b = eps eps'; eq. 1's mixed derivatives cancel)
///                   = 2/(3 sqrt 3) wGrad^2 (t_01 + t_20 + t_21),  t_kl = U_k(p) U_l(b) - U_l(p) U_k(b),
/// each t_kl being (grad p x grad b)(e_k x e_l) / wGrad^2 with e_k x e_l = sqrt(3)/2.
inline double kobayashiEuler(const float* p, const float* T, const float* a, const float* cx, const float* cy,
                             const float* gx, const float* gy, const float* gz, std::size_t i,
                             const FlatStencil& st, const KobayashiParams& k, double Te, double chi,
                             float& pOut, float& tOut)
{
    const double p0 = p[i], t0 = T[i], a0 = a[i];
    double lo = p0, hi = p0;
    for (int q = 0; q < st.n; ++q) {
        const double v = p[i + st.off[q]];
        lo = std::min(lo, v); // std::min/max inline; fmin/fmax are libm calls (NaN rules)
        hi = std::max(hi, v);
    }
    const double lapP = eulerLaplacian(p, i, st), lapT = eulerLaplacian(T, i, st);
    double rest; // the anisotropic part
    if (st.d6) {
        double Up[3], Ua[3], Ub[3];
        hexProjections(p, i, st, Up);
        hexProjections(a, i, st, Ua);
        hexProjections(cx, i, st, Ub);
        double dot[3] = {Ua[0] * Up[0], Ua[1] * Up[1], Ua[2] * Up[2]};
        double t[3] = {Up[0] * Ub[1] - Up[1] * Ub[0], Up[2] * Ub[0] - Up[0] * Ub[2], Up[2] * Ub[1] - Up[1] * Ub[2]};
        const double w2 = st.wGrad[0] * st.wGrad[0];
        rest = (2.0 / 3.0) * w2 * canonicalSum(dot, 3) + (2.0 / (3.0 * std::sqrt(3.0))) * w2 * canonicalSum(t, 3);
    } else {
        const double cx0 = cx[i], cy0 = cy[i];
        double dax = 0, day = 0, daz = 0, cross = 0;
        for (int q = 0; q < st.n; ++q) {
            const std::size_t j = i + st.off[q];
            const double da = st.wGrad[q] * (double(a[j]) - a0);
            dax += da * st.ex[q];
            day += da * st.ey[q];
            daz += da * st.ez[q];
            cross += st.wGrad[q] * (-st.ex[q] * (double(cy[j]) - cy0) + st.ey[q] * (double(cx[j]) - cx0));
        }
        rest = dax * gx[i] + day * gy[i] + daz * gz[i] + cross;
    }
    const double m = k.alpha / M_PI * std::atan(k.gamma * (Te - t0));
    const double reaction = p0 * (1.0 - p0) * (p0 - 0.5 + m + k.noise * chi);
    const double r = k.dt / k.tau;
    const double pMono = p0 + r * (a0 * lapP + reaction);
    const double pNew = std::min(std::max(pMono, hi), std::max(std::min(pMono, lo), pMono + r * rest));
    const double dp = pNew - p0;
    pOut = float(pNew + 0.0); // + 0.0: an exact zero is +0, as kobayashiEulerHeatOnly writes
    tOut = float(t0 + k.dt * lapT + k.latentHeat * dp);
    return dp;
}

/// kobayashiEuler at a cell whose p is exactly 0 at every cell within two stencil steps (the
/// whole neighbourhood pass 1 and 2 read): there the anisotropy coefficients are constants, every
/// term of dp is an exact zero, so p stays 0 and T takes the plain heat step; the same
/// operations in the same order give the same bits. Keep in step with kobayashiEuler's T update.
inline void kobayashiEulerHeatOnly(const float* T, std::size_t i, const FlatStencil& st, const KobayashiParams& k,
                                   float& pOut, float& tOut)
{
    const double t0 = T[i];
    const double lapT = eulerLaplacian(T, i, st);
    const double dp = 0.0;
    pOut = 0.f;
    tOut = float(t0 + k.dt * lapT + k.latentHeat * dp);
}

/// eps(theta)^2 at cell i for the gradient of @a u: the only anisotropic coefficient of eq. 8.
/// The anisotropy fades out where u is flat: eps = eps_bar (1 + delta f cos(j (theta0 - theta)))
/// with f = (|g|^2 / (|g|^2 + sigma^2))^(j/2), sigma = kFlatGradientPerCell / h. Where there is
/// no interface the normal angle theta is undefined, and where |g| is of the order of a step's
/// error, that error turns theta (and eps^2) by O(1): the coefficients' extrapolation to the
/// midpoint, second order elsewhere, was first order there, and so was the whole scheme with
/// anisotropy (observed 1.6 -> 1.3 as dt shrank). f makes eps^2 a smooth function of grad u;
/// f > 0.99 where p changes by more than 0.1 per cell (every interface).
/// On the hexagonal lattice with j = 6 and the arms on lattice directions it is evaluated from
/// the three pair differences D_k = u(+e_k) - u(-e_k) alone, by functions that a 60-degree
/// rotation or a mirror (which permute the D_k and flip their signs) leave bit-identical:
///   with u_k = g . e_k (exact: D_m + (D_a/2 +- D_b/2)), |g|^2 = 2/3 sum u_k^2 and
///   cos 6 theta = 32 (u_0 u_1 u_2)^2 / |g|^6 - 1 = 108 prod u_k^2 / (sum u_k^2)^3 - 1,
/// products and sums in canonical order. Elsewhere: the generic form (Anisotropy), which the
/// square lattice's axis-aligned taps already keep exactly D4-symmetric.
inline double kobayashiEpsSquared(const float* u, std::size_t i, const FlatStencil& st, const Anisotropy& an)
{
    if (st.hexagonal && an.integerMode == 6 && an.sj0 == 0.0) {
        double D[3];
        for (int k = 0; k < 3; ++k) D[k] = double(u[i + st.off[2 * k]]) - double(u[i + st.off[2 * k + 1]]);
        // Taps 0/1: 0 degrees, 2/3: 60, 4/5: -60. e0.e60 = e0.e-60 = 1/2, e60.e-60 = -1/2.
        const double u0 = D[0] + (0.5 * D[1] + 0.5 * D[2]);
        const double u1 = D[1] + (0.5 * D[0] - 0.5 * D[2]);
        const double u2 = D[2] + (0.5 * D[0] - 0.5 * D[1]);
        double sq[3] = {u0 * u0, u1 * u1, u2 * u2};
        {   // sorted by a min/max network (no data-dependent branches), as canonicalSum
            const double a = std::min(sq[0], sq[1]), b = std::max(sq[0], sq[1]);
            const double t = std::max(a, sq[2]);
            sq[0] = std::min(a, sq[2]);
            sq[1] = std::min(b, t);
            sq[2] = std::max(b, t);
        }
        const double S = (sq[0] + sq[1]) + sq[2];
        double c6 = 1.0; // no gradient: theta = 0 (as the generic form)
        if (S > 1e-300) c6 = 108.0 * ((sq[0] * sq[1]) * sq[2]) / (S * S * S) - 1.0;
        const double g2 = (2.0 / 3.0) * (st.wGrad[0] * st.wGrad[0]) * S; // |grad u|^2
        const double f = g2 / (g2 + st.flatGradient2);
        c6 *= f * f * f;
        const double eps = an.epsBar * (1.0 + an.delta * (an.cj0 * c6));
        return eps * eps;
    }
    double sx = 0, sy = 0;
    const double u0 = u[i];
    for (int q = 0; q < st.n; ++q) {
        const double d = st.wGrad[q] * (double(u[i + st.off[q]]) - u0);
        sx += d * st.ex[q];
        sy += d * st.ey[q];
    }
    double eps, epsPrime;
    an(sx, sy, eps, epsPrime);
    const double g2 = sx * sx + sy * sy;
    eps = an.epsBar + (eps - an.epsBar) * std::pow(g2 / (g2 + st.flatGradient2), 0.5 * an.j);
    return eps * eps;
}

/// fmax / fmin with glibc's results (NaN dropped; a tie of +0 and -0 gives the second argument)
/// but inline: the libm calls cost a tenth of a second-order row.
inline double libmMax(double a, double b) { return (a > b || b != b) ? a : b; }
inline double libmMin(double a, double b) { return (a < b || b != b) ? a : b; }

/// The phase equation's linear operator at cell i in eq. 8's advection-diffusion form,
///   L p = a lap p + c . grad p = sum_q C_q (p_q - p_i),   C_q = a w_q + wGrad_q (c . e_q),
/// a = eps^2 at the cell, c = grad a (central differences of @a a). c . e_q is summed from the
/// pair differences with its exact lattice weights (e_q . e_k in {0, +-1/2, +-1}), the
/// direction's own pair first, so that symmetric images get identical coefficients. Every C_q
/// is kept >= 0 (positive coefficients: no new extrema, hence no overshoot where a walker froze
/// a cell): where the advection would dominate a tap (cell Peclet number |c.e_q| h / (2a) > 1,
/// only for delta above ~0.38), a is raised to |c.e_q| wGrad_q / w_q (upwinding by added
/// diffusion, first order in space there, the time order is untouched). Returns sum_q C_q.
inline double advectionDiffusionCoefficients(const float* a, std::size_t i, const FlatStencil& st, double* C)
{
    const int np = st.n / 2;
    double A[FlatStencil::kMaxTaps / 2];
    for (int k = 0; k < np; ++k) A[k] = st.wGrad[2 * k] * (double(a[i + st.off[2 * k]]) - double(a[i + st.off[2 * k + 1]]));
    double ce[FlatStencil::kMaxTaps];
    double aEff = a[i];
    for (int k = 0; k < np; ++k) {
        // c . e_{2k}: own pair, plus the others with their exact weights (a pair sum, commutative).
        double rest = 0;
        int m = 0;
        double other[FlatStencil::kMaxTaps / 2];
        for (int l = 0; l < np; ++l)
            if (l != k && st.pairDot[k][l] != 0.0) other[m++] = st.pairDot[k][l] * A[l];
        if (m == 1) rest = other[0];
        else if (m == 2) rest = other[0] + other[1];
        else for (int l = 0; l < m; ++l) rest += other[l]; // not reached on the supported lattices
        ce[2 * k] = A[k] + rest;
        ce[2 * k + 1] = -ce[2 * k];
        aEff = libmMax(aEff, std::fabs(ce[2 * k]) * st.wGrad[2 * k] / st.wLap[2 * k]);
    }
    double pair[FlatStencil::kMaxTaps / 2];
    for (int k = 0; k < np; ++k) {
        C[2 * k] = aEff * st.wLap[2 * k] + st.wGrad[2 * k] * ce[2 * k];
        C[2 * k + 1] = aEff * st.wLap[2 * k + 1] + st.wGrad[2 * k + 1] * ce[2 * k + 1];
        pair[k] = C[2 * k] + C[2 * k + 1];
    }
    return canonicalSum(pair, np);
}

/// One row of the second-order step at cell i (eq. 8), theta-weighted (theta = 1/2: Crank-
/// Nicolson, second order; theta = 1: implicit Euler, the start-up steps):
///   p' - theta r L(p') - r N(p') = p + (1 - theta) r L(p),   N linear in p' (see below),
/// r = dt/tau, L the advection-diffusion operator above with its coefficients (a = eps^2 and
/// its gradient) at the step's midpoint, extrapolated from the last increment (pe), as is m(T);
/// the reaction, linear in p', is detailed below (bounded, with an implicit latent-heat loop). The advection sits inside the Crank-Nicolson
/// average with the diffusion: the whole linear operator is time-centred, so the step is second
/// order in time, and positive coefficients make the implicit side an M-matrix and the explicit
/// side a positive combination (dt below the limit), so p stays within its bounds without any
/// clipping. (The paper's Lax-Wendroff advection is dispersive: it overshoots at walker-frozen
/// cells, and as written it is only first order with anisotropy, docs/accuracy.md.)
/// Returned: diag, per-tap coefficients coef (the system is diag p'_i - sum_q coef_q p'_q = rhs),
/// rhs, a bounded first guess and lap T^n for the temperature system. @a pf is the extrapolated
/// p at the end of the step (clamped to [0, 1]), for the latent-heat feedback.
struct SecondOrderRow {
    double diag, rhs, predictor, lapT;
    double coef[FlatStencil::kMaxTaps];
};

/// The reaction's part of a second-order row, linear in p': diag += d, rhs += r.
struct ReactionPart {
    double diag, rhs;
};

/// Reaction n = p (1 - p) g, g = p - 1/2 + m(T) + a chi, linearised about @a pm (the theta-point
/// estimate of p) and taken at p_t = theta p' + (1 - theta) p0: n(pm) + s (p_t - pm), bounded.
/// The slope s is the tangent n'(pm), except where the tangent is a relaxation (s < 0) towards a
/// zero beyond a bound of p: near p = 1 n is concave, and the tangent at pm crosses 0 past 1
/// (where a walker had frozen a cell and the last step thawed it back to 0.85, pm 0.78 put p' at
/// 1.065; 4,312 voxels were clipped in the Figure 7 snowflake). There s is the chord to that
/// bound, which n crosses: -pm g towards 1 (g > 0), (1 - pm) g towards 0 (g < 0). Any slope keeps
/// the step second order (pm - p_t is O(dt^2), the slope only scales an O(dt^3) local term);
/// the tangent keeps the error constant where it is bounded (the chord everywhere cost 4x).
/// A relaxation at rate r |s| (r = dt/tau) is stiff at the paper's dt: the trapezoidal half
/// (1 - theta) r |s| must fit within @a explicitBudget, the explicit weight the diffusion leaves
/// to p0 (1 - (1 - theta) r sum C); where it does not, the reaction takes the larger implicit
/// weight theta_R = 1 - explicitBudget / (r |s|) (stiff cells only). The row is then a convex
/// combination of p0, its neighbours and the relaxation's target in [0, 1], so p' stays in
/// [0, 1]. (A growing tangent, s > 0, is bounded by dt <= tau / max n' instead.)
/// Plus the latent-heat loop: freezing by dp warms the cell by K dp, which lowers m(T) and slows
/// freezing. With gamma large this loop is stiff (rate ~ p(1-p) |m'(T)| K / tau, 16 per step at
/// dt 0.0008 with gamma 30, K 2.5); taken only from the extrapolated te it oscillated and
/// overshot (p 1.044) or thawed frozen arms. T at the theta-point is te plus theta K times the
/// difference between this step's dp and the one the extrapolation assumed (@a pf - p0), an
/// O(dt^2) correction that makes the loop implicit: n += w (p' - pf), w = pm (1-pm) m'(T) theta K
/// (w <= 0: a relaxation towards pf in [0, 1], bounded too).
inline ReactionPart kobayashiReactionPart(double p0, double pm, double pf, double x, double noiseChi,
                                          const KobayashiParams& k, double theta, double explicitBudget = 1.0)
{
    const double r = k.dt / k.tau;
    const double m = k.alpha / M_PI * std::atan(x);
    const double g = pm - 0.5 + m + noiseChi;
    const double n0 = pm * (1.0 - pm) * g;
    double s = (1.0 - 2.0 * pm) * g + pm * (1.0 - pm);
    if (s < 0) {
        const double zero = pm - n0 / s; // where the tangent vanishes
        if (zero > 1.0) s = -pm * g;
        else if (zero < 0.0) s = (1.0 - pm) * g;
    }
    double thetaR = theta;
    if (s < 0 && -(1.0 - theta) * r * s > explicitBudget) thetaR = 1.0 + libmMax(0.0, explicitBudget) / (r * s);
    const double dmdT = -k.alpha / M_PI * k.gamma / (1.0 + x * x);
    const double w = pm * (1.0 - pm) * dmdT * theta * k.latentHeat; // <= 0
    // n = n0 + s (thetaR p' + (1 - thetaR) p0 - pm); below the stability limit the diagonal stays > 0.
    return {-thetaR * r * s - r * w, r * (n0 - s * pm + s * (1.0 - thetaR) * p0) - r * w * pf};
}

inline SecondOrderRow kobayashiSecondOrderRow(const float* p, const float* T, const float* pe, const float* te,
                                              const float* pf, const float* a, std::size_t i, const FlatStencil& st,
                                              const KobayashiParams& k, double Te, double chi, double theta)
{
    SecondOrderRow row;
    double C[FlatStencil::kMaxTaps];
    const double sumC = advectionDiffusionCoefficients(a, i, st, C);
    const double Lp = symmetricTapSum(p, i, st, C);
    row.lapT = symmetricTapSum(T, i, st, st.wLap);
    const double p0 = p[i];
    const double r = k.dt / k.tau;
    const double x = k.gamma * (Te - double(te[i]));
    for (int q = 0; q < st.n; ++q) row.coef[q] = theta * r * C[q];
    const ReactionPart rp =
        kobayashiReactionPart(p0, pe[i], pf[i], x, k.noise * chi, k, theta, 1.0 - (1.0 - theta) * r * sumC);
    row.diag = 1.0 + theta * r * sumC + rp.diag;
    row.rhs = p0 + (1.0 - theta) * r * Lp + rp.rhs;
    // Forward Euler guess, kept in [0, 1] so that even a loosely converged solve starts inside
    // the bounds (the solver's iterates are then convex combinations of in-bound values).
    const ReactionPart ex = kobayashiReactionPart(p0, pe[i], pf[i], x, k.noise * chi, k, 0.0);
    row.predictor = libmMin(1.0, libmMax(0.0, p0 + r * Lp + ex.rhs - ex.diag * p0));
    return row;
}

} // namespace frostvdb
