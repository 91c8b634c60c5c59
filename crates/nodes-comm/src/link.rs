//! The UHF downlink as COMM reports it: geometry towards the configured ground stations and
//! a free-space link budget.
//!
//! # Model
//! - Geometry: the truth position (ECI J2000) is rotated to ECEF at the snapshot's UTC
//!   (`orbit::frames::a_ecef_from_eci`, no EOP, the same rotation the twin's pass
//!   prediction uses) and seen from each station's WGS-84 site
//!   (`orbit::passes::GroundSite::look_angles`: geodetic elevation, no refraction).
//! - Station choice: among the stations at or above the elevation mask, the nearest (least
//!   slant range); with none above the mask, the nearest of all. The link is **in contact**
//!   when the chosen station is at or above the mask (the same rule the twin uses to open the
//!   air link during passes).
//! - Budget (satellite -> ground, the direction a ground operator measures):
//!   `signal = EIRP + G_rx - FSPL(range, f) - L_other`, with
//!   `FSPL = 20 log10(4 pi d f / c)`; noise `N = 10 log10(k T_sys B) + 30` dBm. In contact
//!   the RSSI is the power sum of signal and noise and the SNR is `signal - N`; out of
//!   contact the receiver hears only noise (RSSI = N, SNR reported as 0).
//!
//! Default numbers ([`LinkBudget::default`]): 1 W transmitter (30 dBm) into a 0 dBi
//! turnstile/monopole with 1 dB of line loss: EIRP 29 dBm; ground crossed Yagi 14 dBi
//! (typical 2 x 10-element 70 cm antenna); 3 dB other losses (polarisation mismatch,
//! pointing, atmosphere); 437 MHz (amateur-satellite UHF band); T_sys 500 K (sky and
//! man-made noise at 70 cm plus LNA and cable) in B = 20 kHz (a 9600 bit/s GMSK channel),
//! N = -128.6 dBm. At 600 km overhead: FSPL 140.8 dB, signal -100.8 dBm, SNR 27.8 dB; at the
//! 10 deg mask from 520 km altitude (about 1740 km): FSPL 150.1 dB, SNR 18.5 dB.

use nalgebra::Vector3;
use orbit::frames::a_ecef_from_eci;
use orbit::passes::GroundSite;
use orbit::time::UtcTime;
use platform::truth::TruthSnapshot;

/// Speed of light, m/s (SI definition).
pub const C_M_S: f64 = 299_792_458.0;
/// Boltzmann constant, J/K (SI definition).
pub const BOLTZMANN_J_K: f64 = 1.380_649e-23;

/// A ground station of the UHF network.
#[derive(Debug, Clone, PartialEq)]
pub struct Station {
    /// Name for logs (`Vilnius`).
    pub name: String,
    /// Geodetic latitude, deg.
    pub lat_deg: f64,
    /// Longitude, deg.
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, m.
    pub alt_m: f64,
}

impl Station {
    /// The default main ground station: Vilnius (54.6872 N, 25.2797 E, 112 m).
    pub fn vilnius() -> Self {
        Station {
            name: "Vilnius".to_owned(),
            lat_deg: 54.6872,
            lon_deg: 25.2797,
            alt_m: 112.0,
        }
    }
    /// The station's site for look angles.
    pub fn site(&self) -> GroundSite {
        GroundSite::from_deg(self.lat_deg, self.lon_deg, self.alt_m)
    }
}

/// The free-space link budget of the downlink (see the module doc for the defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkBudget {
    /// Satellite EIRP, dBm (transmitter power + antenna gain - line losses).
    pub eirp_dbm: f64,
    /// Ground antenna gain, dBi.
    pub rx_gain_dbi: f64,
    /// Other losses (polarisation, pointing, atmosphere), dB.
    pub other_losses_db: f64,
    /// Carrier frequency, Hz.
    pub frequency_hz: f64,
    /// Receiver system noise temperature, K.
    pub system_noise_temp_k: f64,
    /// Receiver noise bandwidth, Hz.
    pub noise_bandwidth_hz: f64,
}

impl Default for LinkBudget {
    fn default() -> Self {
        LinkBudget {
            eirp_dbm: 29.0,
            rx_gain_dbi: 14.0,
            other_losses_db: 3.0,
            frequency_hz: 437e6,
            system_noise_temp_k: 500.0,
            noise_bandwidth_hz: 20e3,
        }
    }
}

impl LinkBudget {
    /// Free-space path loss over `range_km`, dB (`20 log10(4 pi d f / c)`; 0 at d = 0).
    pub fn fspl_db(&self, range_km: f64) -> f64 {
        let x = 4.0 * std::f64::consts::PI * range_km * 1e3 * self.frequency_hz / C_M_S;
        if x > 1.0 { 20.0 * x.log10() } else { 0.0 }
    }
    /// Received signal power at `range_km`, dBm.
    pub fn signal_dbm(&self, range_km: f64) -> f64 {
        self.eirp_dbm + self.rx_gain_dbi - self.fspl_db(range_km) - self.other_losses_db
    }
    /// Receiver noise floor `k T B`, dBm.
    pub fn noise_dbm(&self) -> f64 {
        let w = BOLTZMANN_J_K * self.system_noise_temp_k * self.noise_bandwidth_hz;
        if w > 0.0 {
            10.0 * w.log10() + 30.0
        } else {
            f64::NEG_INFINITY
        }
    }
}

/// COMM's view of the link at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkState {
    /// Index of the chosen station in the configuration.
    pub station: usize,
    /// Whether the chosen station is at or above the mask.
    pub in_contact: bool,
    /// Elevation, deg.
    pub elevation_deg: f64,
    /// Azimuth, deg from north through east.
    pub azimuth_deg: f64,
    /// Slant range, km.
    pub range_km: f64,
    /// Received signal power from the budget, dBm (whatever the elevation).
    pub signal_dbm: f64,
    /// RSSI: signal plus noise in contact, noise alone out of contact, dBm.
    pub rssi_dbm: f64,
    /// SNR in contact, 0 out of contact, dB.
    pub snr_db: f64,
}

/// The truth position in ECEF, km, at the snapshot's UTC.
pub fn r_ecef_km(truth: &TruthSnapshot) -> Vector3<f64> {
    let t = UtcTime::from_unix_ns(truth.unix_ns);
    a_ecef_from_eci(t, None) * truth.r_eci_m * 1e-3
}

/// The link towards the best of `sites` (see the module doc); `None` without stations.
pub fn link_state(
    sites: &[GroundSite],
    mask_deg: f64,
    budget: &LinkBudget,
    r_ecef_km: &Vector3<f64>,
) -> Option<LinkState> {
    let looks: Vec<_> = sites.iter().map(|s| s.look_angles(r_ecef_km)).collect();
    let above = |i: &usize| looks[*i].elevation_rad.to_degrees() >= mask_deg;
    let nearest = |it: &mut dyn Iterator<Item = usize>| {
        it.min_by(|&a, &b| looks[a].range_km.total_cmp(&looks[b].range_km))
    };
    let station =
        nearest(&mut (0..looks.len()).filter(above)).or_else(|| nearest(&mut (0..looks.len())))?;
    let look = looks[station];
    let in_contact = above(&station);
    let signal_dbm = budget.signal_dbm(look.range_km);
    let noise = budget.noise_dbm();
    let (rssi_dbm, snr_db) = if in_contact {
        let sum_mw = 10f64.powf(signal_dbm / 10.0) + 10f64.powf(noise / 10.0);
        (10.0 * sum_mw.log10(), signal_dbm - noise)
    } else {
        (noise, 0.0)
    };
    Some(LinkState {
        station,
        in_contact,
        elevation_deg: look.elevation_rad.to_degrees(),
        azimuth_deg: look.azimuth_rad.to_degrees(),
        range_km: look.range_km,
        signal_dbm,
        rssi_dbm,
        snr_db,
    })
}

snap::fields!(Station {
    name,
    lat_deg,
    lon_deg,
    alt_m
});
snap::fields!(LinkBudget {
    eirp_dbm,
    rx_gain_dbi,
    other_losses_db,
    frequency_hz,
    system_noise_temp_k,
    noise_bandwidth_hz
});

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budget_numbers_match_the_documented_ones() {
        let b = LinkBudget::default();
        // 20 log10(4 pi 600e3 437e6 / c) = 140.820 dB (computed independently).
        assert!((b.fspl_db(600.0) - 140.820).abs() < 1e-3);
        assert!((b.fspl_db(1000.0) - 145.257).abs() < 1e-3);
        assert!((b.noise_dbm() - -128.599).abs() < 1e-3);
        assert!((b.signal_dbm(600.0) - -100.820).abs() < 1e-3);
        // Twice the range: 6.02 dB weaker.
        assert!((b.signal_dbm(600.0) - b.signal_dbm(1200.0) - 6.0206).abs() < 1e-3);
    }
}
