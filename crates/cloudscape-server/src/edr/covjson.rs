//! CoverageJSON (OGC CoverageJSON 1.0) documents: the coverages the EDR queries
//! answer and the parameter descriptions the collections list. Plain ordered structs,
//! so the same answer is the same bytes.

use std::collections::BTreeMap;

use serde::Serialize;

use super::query::{Quantity, format_instant};

/// The media type of CoverageJSON.
pub const MEDIA_TYPE: &str = "application/prs.coverage+json";

/// UCUM, the unit symbol scheme of every parameter.
pub const UCUM: &str = "http://www.opengis.net/def/uom/UCUM/";

/// An internationalised string; ours are English.
#[derive(Clone, Debug, Serialize)]
pub struct I18n {
    pub en: String,
}

fn en(text: &str) -> I18n {
    I18n { en: text.to_string() }
}

#[derive(Clone, Debug, Serialize)]
pub struct Symbol {
    pub value: &'static str,
    #[serde(rename = "type")]
    pub scheme: &'static str,
}

#[derive(Clone, Debug, Serialize)]
pub struct Unit {
    pub label: I18n,
    pub symbol: Symbol,
}

#[derive(Clone, Debug, Serialize)]
pub struct ObservedProperty {
    /// The CF standard name's vocabulary entry, where one means the same thing.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<&'static str>,
    pub label: I18n,
}

/// A CoverageJSON parameter object (also an EDR collection's `parameter_names` entry).
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Parameter {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub description: I18n,
    pub unit: Unit,
    pub observed_property: ObservedProperty,
}

/// What a quantity is, in words: the texts of its CoverageJSON parameter here and of
/// its EDR `parameter_names` entry ([`super::metadata`]), which writes them as plain
/// strings where CoverageJSON has internationalised objects.
pub struct QuantityText {
    pub label: &'static str,
    pub description: &'static str,
    /// The unit's name.
    pub unit: &'static str,
    /// The unit's UCUM symbol.
    pub symbol: &'static str,
    /// The observed property's vocabulary entry, where one means the same thing.
    pub id: Option<&'static str>,
}

/// What each quantity means, in the words of `region_stats` and `weather`.
pub fn text(q: Quantity) -> QuantityText {
    let (label, description, unit, symbol, id) = match q {
        Quantity::CloudCover => (
            "Cloud cover",
            "Per column: 1 when any cell of the column has density >= 0.1 (cloudy), else 0; the mean over \
             columns is /region's coverage. Per cell (cube with z): 1 when the cell is cloudy, else 0. At a \
             position: 1 when the column above the point (every layer whose top is above z, or the layer \
             named) holds a cloudy cell.",
            "fraction",
            "1",
            Some("http://vocab.nerc.ac.uk/standard_name/cloud_area_fraction/"),
        ),
        Quantity::Density => (
            "Cloud density",
            "The smoothed automaton density in [0, 1]. Per column: the mean over the column's cells (the mean \
             over columns is /region's mean_density). Per cell (cube with z) and at a position: the density \
             of the cell, as /sample answers it (0 outside every layer).",
            "dimensionless",
            "1",
            None,
        ),
        Quantity::CloudBase => (
            "Cloud base altitude",
            "Altitude above sea level of the bottom of the lowest cloudy cell of the column; null when the \
             column is clear.",
            "metre",
            "m",
            Some("http://vocab.nerc.ac.uk/standard_name/cloud_base_altitude/"),
        ),
        Quantity::CloudTop => (
            "Cloud top altitude",
            "Altitude above sea level of the top of the highest cloudy cell of the column; null when the \
             column is clear.",
            "metre",
            "m",
            Some("http://vocab.nerc.ac.uk/standard_name/cloud_top_altitude/"),
        ),
        Quantity::PrecipitationRate => (
            "Precipitation rate",
            "Liquid-water-equivalent rate of the column (cloudscape_core::weather::precipitation); at a \
             position the sum over the layers above it, as /sample's precipitation_mm_h.",
            "millimetre per hour",
            "mm/h",
            Some("http://vocab.nerc.ac.uk/standard_name/lwe_precipitation_rate/"),
        ),
    };
    QuantityText {
        label,
        description,
        unit,
        symbol,
        id,
    }
}

/// The CoverageJSON parameter object of a quantity.
pub fn parameter(q: Quantity) -> Parameter {
    let t = text(q);
    Parameter {
        kind: "Parameter",
        description: en(t.description),
        unit: Unit {
            label: en(t.unit),
            symbol: Symbol {
                value: t.symbol,
                scheme: UCUM,
            },
        },
        observed_property: ObservedProperty {
            id: t.id,
            label: en(t.label),
        },
    }
}

/// One axis of a domain.
#[derive(Clone, Debug, Serialize)]
#[serde(untagged)]
pub enum Axis {
    Numbers { values: Vec<f64> },
    Regular { start: f64, stop: f64, num: usize },
    Times { values: Vec<String> },
}

impl Axis {
    /// The centres of `n` columns of width `w` from column `first`.
    pub fn columns(first: i64, n: usize, w: f64) -> Axis {
        Axis::Regular {
            start: (first as f64 + 0.5) * w,
            stop: (first as f64 + n as f64 - 0.5) * w,
            num: n,
        }
    }

    /// World times as ISO 8601 instants.
    pub fn times(times: &[f64]) -> Axis {
        Axis::Times {
            values: times.iter().map(|&t| format_instant(t)).collect(),
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct Axes {
    pub x: Axis,
    pub y: Axis,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z: Option<Axis>,
    pub t: Axis,
}

/// A reference system object.
#[derive(Clone, Debug, Serialize)]
pub struct System {
    #[serde(rename = "type")]
    pub kind: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calendar: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub description: Option<I18n>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Referencing {
    pub coordinates: Vec<&'static str>,
    pub system: System,
}

/// The reference systems of our axes: x, y in the world's plane, z altitude above sea
/// level when there is a z axis, t the Gregorian calendar (world time t = the Unix
/// epoch + t seconds).
///
/// The plane is, in ISO 19111's terms, an engineering CRS (not tied to the Earth; the
/// collections give its WKT 2 `ENGCRS`). CoverageJSON 1.0 defines the types
/// GeographicCRS, ProjectedCRS, VerticalCRS, TemporalRS and IdentifierRS; its schema
/// admits other types, but validators (covjson-pydantic) refuse them. So the type is
/// `ProjectedCRS`, CoverageJSON's type for planar easting/northing in metres, which
/// both accept, with no `id` (no EPSG code names a game world) and a description that
/// says what the plane is.
pub fn referencing(with_z: bool) -> Vec<Referencing> {
    let mut r = vec![Referencing {
        coordinates: vec!["x", "y"],
        system: System {
            kind: "ProjectedCRS",
            calendar: None,
            description: Some(en(
                "The game world's plane, not georeferenced: a local engineering CRS (WKT 2 ENGCRS in the \
                 collection's extent) in metres, x east, y north, origin at the corner of tile (z, 0, 0).",
            )),
        },
    }];
    if with_z {
        r.push(Referencing {
            coordinates: vec!["z"],
            system: System {
                kind: "VerticalCRS",
                calendar: None,
                description: Some(en("Altitude above sea level, metres, up.")),
            },
        });
    }
    r.push(Referencing {
        coordinates: vec!["t"],
        system: System {
            kind: "TemporalRS",
            calendar: Some("Gregorian"),
            description: None,
        },
    });
    r
}

#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Domain {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub domain_type: &'static str,
    pub axes: Axes,
    pub referencing: Vec<Referencing>,
}

/// The values of a range: `f32` where the answer is a cell's density (written as
/// `/sample` writes it), `f64` otherwise; `null` for no value.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Values {
    F32(Vec<Option<f32>>),
    F64(Vec<Option<f64>>),
}

/// A range: a row-major array over `axis_names` (none for a single value).
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct NdArray {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub data_type: &'static str,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub axis_names: Vec<&'static str>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub shape: Vec<usize>,
    pub values: Values,
}

#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Coverage {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub domain: Domain,
    pub parameters: BTreeMap<&'static str, Parameter>,
    pub ranges: BTreeMap<&'static str, NdArray>,
}

impl Coverage {
    /// A coverage of `domain_type` over `axes`, with one range per quantity, each of
    /// `shape` over `axis_names`.
    pub fn new(
        domain_type: &'static str,
        axes: Axes,
        axis_names: Vec<&'static str>,
        shape: Vec<usize>,
        ranges: Vec<(Quantity, Values)>,
    ) -> Coverage {
        let with_z = axes.z.is_some();
        Coverage {
            kind: "Coverage",
            domain: Domain {
                kind: "Domain",
                domain_type,
                axes,
                referencing: referencing(with_z),
            },
            parameters: ranges.iter().map(|(q, _)| (q.name(), parameter(*q))).collect(),
            ranges: ranges
                .into_iter()
                .map(|(q, values)| {
                    (
                        q.name(),
                        NdArray {
                            kind: "NdArray",
                            data_type: "float",
                            axis_names: axis_names.clone(),
                            shape: shape.clone(),
                            values,
                        },
                    )
                })
                .collect(),
        }
    }
}
