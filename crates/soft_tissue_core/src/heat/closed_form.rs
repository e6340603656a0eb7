//! Closed-form temperature fields the heat model is checked against (and the error function
//! they need): a sphere heated at constant power in an infinite medium (Carslaw and Jaeger,
//! *Conduction of Heat in Solids*, 2nd ed., 1959, section 9.10, constant flux at the surface
//! of a spherical cavity) and its steady state with Pennes perfusion. An electrode half-sunk
//! at an insulated flat surface gives the same field at twice the power (by images).

use std::f64::consts::PI;

/// `erfc(x)`, the complementary error function, to about 1e-13 relative (a power series
/// below 2, a continued fraction above).
pub fn erfc(x: f64) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    if x.is_infinite() {
        return if x > 0.0 { 0.0 } else { 2.0 };
    }
    if x < 0.0 {
        return 2.0 - erfc(-x);
    }
    if x < 2.0 {
        1.0 - erf_series(x)
    } else {
        (-x * x).exp() * erfcx_fraction(x)
    }
}

/// `exp(x^2) erfc(x)`, finite for large `x` where `erfc` underflows.
pub fn erfcx(x: f64) -> f64 {
    if x < 2.0 {
        (x * x).exp() * erfc(x)
    } else {
        erfcx_fraction(x)
    }
}

/// `erf(x) = 2/sqrt(pi) exp(-x^2) sum 2^n x^(2n+1) / (1 3 5 ... (2n+1))` for `x >= 0`: all
/// terms positive, so no cancellation.
fn erf_series(x: f64) -> f64 {
    let x2 = x * x;
    let mut term = x;
    let mut sum = x;
    let mut n = 0.0;
    while term > 1e-17 * sum {
        n += 1.0;
        term *= 2.0 * x2 / (2.0 * n + 1.0);
        sum += term;
    }
    2.0 / PI.sqrt() * (-x2).exp() * sum
}

/// `exp(x^2) erfc(x)` for `x >= 2` by the continued fraction
/// `1/sqrt(pi) 1 / (x + (1/2) / (x + 1 / (x + (3/2) / (x + ...))))`, evaluated by the
/// modified Lentz method.
fn erfcx_fraction(x: f64) -> f64 {
    let tiny = 1e-300;
    let mut f = x;
    let mut c = x;
    let mut d = 0.0;
    for k in 1..1000 {
        let a = k as f64 / 2.0;
        d = x + a * d;
        if d.abs() < tiny {
            d = tiny;
        }
        c = x + a / c;
        if c.abs() < tiny {
            c = tiny;
        }
        d = 1.0 / d;
        let delta = c * d;
        f *= delta;
        if (delta - 1.0).abs() < 1e-16 {
            break;
        }
    }
    1.0 / (PI.sqrt() * f)
}

/// Temperature rise, K, at distance `r` (m, at least `a`) from the centre of a sphere of
/// radius `a` (m) that has delivered `power` W into an infinite medium of conductivity `k`
/// (W/(m K)) and diffusivity `kappa` (m^2/s) since time 0, at time `t` (s) (Carslaw and
/// Jaeger, section 9.10):
///
/// ```text
/// P / (4 pi k r) [erfc(x) - exp((r - a)/a + kappa t / a^2) erfc(x + sqrt(kappa t) / a)],
/// x = (r - a) / (2 sqrt(kappa t))
/// ```
///
/// Its limit at long times is the steady `P / (4 pi k r)`.
pub fn sphere_rise(power: f64, a: f64, k: f64, kappa: f64, r: f64, t: f64) -> f64 {
    if t <= 0.0 {
        return 0.0;
    }
    let s = (kappa * t).sqrt();
    let x = (r - a) / (2.0 * s);
    let y = x + s / a;
    // exp((r - a)/a + kappa t / a^2) erfc(y) = erfcx(y) exp(-x^2): the exponents cancel.
    power / (4.0 * PI * k * r) * (erfc(x) - erfcx(y) * (-x * x).exp())
}

/// Steady temperature rise, K, at distance `r` (m) from the centre of a sphere of radius `a`
/// delivering `power` W into tissue with Pennes perfusion, whose perfusion length is
/// `length = sqrt(k / (w rho_b c_b))` (m): `T'' + 2 T' / r = T / L^2` with the flux
/// `P / (4 pi a^2)` at `r = a` gives
///
/// ```text
/// P exp(-(r - a) / L) / (4 pi k r (1 + a / L))
/// ```
pub fn pennes_sphere_steady(power: f64, a: f64, k: f64, length: f64, r: f64) -> f64 {
    power * (-(r - a) / length).exp() / (4.0 * PI * k * r * (1.0 + a / length))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erfc_matches_tabulated_values() {
        // Abramowitz and Stegun, table 7.1, and erfc(x) = 1 - erf(x).
        let table = [
            (0.0, 1.0),
            (0.5, 0.479_500_122_186_953_5),
            (1.0, 0.157_299_207_050_285_13),
            (2.0, 0.004_677_734_981_047_266),
            (3.0, 2.209_049_699_858_544e-5),
            (5.0, 1.537_459_794_428_035e-12),
        ];
        for (x, v) in table {
            assert!((erfc(x) - v).abs() <= 1e-13 * v, "erfc({x}) = {}", erfc(x));
        }
        assert!((erfc(-1.0) - (2.0 - 0.157_299_207_050_285_13)).abs() < 1e-15);
        assert_eq!((erfc(f64::INFINITY), erfc(f64::NEG_INFINITY)), (0.0, 2.0));
        // Continuity where the two methods meet.
        let below = erfc(2.0 - 1e-12);
        assert!((below - erfc(2.0)).abs() < 1e-11 * erfc(2.0));
        // Its asymptote: erfcx(x) -> 1 / (x sqrt(pi)).
        let x = 1e4;
        assert!((erfcx(x) * x * PI.sqrt() - 1.0).abs() < 1e-8);
    }

    #[test]
    fn sphere_rise_solves_the_heat_equation_with_its_flux() {
        // Finite differences: rho c dT/dt = k (T'' + 2 T'/r) inside, -k T'(a) = P / (4 pi a^2).
        let (p, a, k, rho_c) = (0.5, 1e-3, 0.52, 1079.0 * 3540.0);
        let kappa = k / rho_c;
        let f = |r: f64, t: f64| sphere_rise(p, a, k, kappa, r, t);
        for &(r, t) in &[(1.5e-3, 1.0), (2e-3, 5.0), (3e-3, 20.0)] {
            let (h, dt) = (1e-6, 1e-4);
            let dtdt = (f(r, t + dt) - f(r, t - dt)) / (2.0 * dt);
            let d1 = (f(r + h, t) - f(r - h, t)) / (2.0 * h);
            let d2 = (f(r + h, t) - 2.0 * f(r, t) + f(r - h, t)) / (h * h);
            let lhs = rho_c * dtdt;
            let rhs = k * (d2 + 2.0 * d1 / r);
            assert!(
                (lhs - rhs).abs() < 1e-4 * lhs.abs(),
                "r {r} t {t}: {lhs} {rhs}"
            );
        }
        let h = 1e-8;
        let flux = -k * (f(a + h, 3.0) - f(a, 3.0)) / h;
        assert!((flux - p / (4.0 * PI * a * a)).abs() < 1e-3 * flux);
        // Long times: the steady field.
        assert!((f(2e-3, 1e7) / (p / (4.0 * PI * k * 2e-3)) - 1.0).abs() < 1e-3);
    }

    #[test]
    fn pennes_steady_solves_its_equation_with_its_flux() {
        let (p, a, k, l) = (0.5, 1e-3, 0.52, 3e-3);
        let f = |r: f64| pennes_sphere_steady(p, a, k, l, r);
        let (r, h) = (2.5e-3, 1e-6);
        let d1 = (f(r + h) - f(r - h)) / (2.0 * h);
        let d2 = (f(r + h) - 2.0 * f(r) + f(r - h)) / (h * h);
        assert!(((d2 + 2.0 * d1 / r) - f(r) / (l * l)).abs() < 1e-5 * f(r) / (l * l));
        let flux = -k * (f(a + 1e-9) - f(a)) / 1e-9;
        assert!((flux - p / (4.0 * PI * a * a)).abs() < 1e-4 * flux);
    }
}
