//! `[comm]`: the radio link to the ground as a scenario writes it (docs/scenarios.md, "The
//! radio link").

use schemars::JsonSchema;
use serde::Deserialize;

use crate::dur::Dur;

/// The UHF link to the ground (`[comm]`).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CommSpec {
    /// Model passes: the link closes only while the satellite is above the elevation mask
    /// of a ground station (default false: always in contact, for development).
    #[serde(default)]
    pub passes: bool,
    /// Elevation mask, deg (default 10).
    #[serde(default = "default_mask_deg")]
    pub elevation_mask_deg: f64,
    /// The ground stations' sites (default: Vilnius).
    #[serde(default = "default_stations")]
    pub stations: Vec<StationSpec>,
    /// COMM's beacon period (default 60 s; `0s` switches beacons off; else 10 s to 1 h).
    #[serde(default)]
    pub beacon_period: Option<Dur>,
}

impl Default for CommSpec {
    fn default() -> Self {
        CommSpec {
            passes: false,
            elevation_mask_deg: default_mask_deg(),
            stations: default_stations(),
            beacon_period: None,
        }
    }
}

fn default_mask_deg() -> f64 {
    10.0
}

fn default_stations() -> Vec<StationSpec> {
    vec![StationSpec {
        name: "Vilnius".to_owned(),
        lat_deg: 54.6872,
        lon_deg: 25.2797,
        alt_m: 112.0,
    }]
}

/// A ground station site (WGS-84).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct StationSpec {
    /// Name for logs.
    pub name: String,
    /// Geodetic latitude, deg.
    pub lat_deg: f64,
    /// Longitude, deg (east positive).
    pub lon_deg: f64,
    /// Height above the ellipsoid, m.
    #[serde(default)]
    pub alt_m: f64,
}
