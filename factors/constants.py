"""Physical constants in SI units; the unit is part of every name.

The single source of constants: ``factors`` needs them and never imports ``fgnav``;
``fgnav.constants`` re-exports this module.
"""

__all__ = [
    "MU_EARTH_M3_S2", "R_EARTH_M", "J2_EARTH", "R_LIMB_UV_M", "MU_SUN_M3_S2",
    "MU_MOON_M3_S2", "AU_M", "C_LIGHT_M_S", "DEG", "ARCSEC", "OMEGA_EARTH_RAD_S", "R_SUN_M",
    "J2_MOON", "R_MOON_J2_M", "R_MOON_M",
]

MU_EARTH_M3_S2 = 3.986004418e14
"""Earth gravitational parameter (EGM2008), m^3/s^2."""
R_EARTH_M = 6378137.0
"""Earth equatorial radius (WGS-84 / EGM2008), m."""
J2_EARTH = 1.08262668e-3
"""Earth J2 zonal harmonic (EGM2008), dimensionless."""
R_LIMB_UV_M = 6375.0e3
"""Limb radius of the UV horizon (Wu et al.; Pan & Yao 2017), m: a parameter, not R_e."""
MU_SUN_M3_S2 = 1.32712440018e20
MU_MOON_M3_S2 = 4.9028e12
J2_MOON = 2.032732576e-4
"""The Moon's J2 (DE421's constant J2M; Folkner, Williams & Boggs 2009), with
:data:`R_MOON_J2_M` its reference radius."""
R_MOON_J2_M = 1738.0e3
"""Reference radius of the Moon's gravity field in DE421 (and LP150Q), m."""
R_MOON_M = 1737.4e3
"""The Moon's mean radius (IAU WGCCRE 2009; Archinal et al. 2011), m: its limb sphere."""
AU_M = 1.495978707e11
R_SUN_M = 6.957e8
"""Nominal solar radius (IAU 2015 Resolution B3), m: the photosphere."""
C_LIGHT_M_S = 299792458.0
DEG = 0.017453292519943295
"""Radians per degree."""
ARCSEC = DEG / 3600.0
"""Radians per arcsecond."""
OMEGA_EARTH_RAD_S = 7.2921150e-5
"""Earth rotation rate, rad/s."""
