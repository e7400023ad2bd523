//! `cloudscape serve`: the HTTP service.
//!
//! Configuration, lowest precedence first: the embedded default or `--config FILE`
//! (also `CLOUDSCAPE_CONFIG`), then environment overrides of `[server]` and `[limits]`
//! keys (`CLOUDSCAPE_SERVER_LISTEN=0.0.0.0:8080`, `CLOUDSCAPE_LIMITS_MAX_LEVEL=12`,
//! values in TOML syntax or plain strings), then `--listen`. The result is validated
//! like any config file; `--print-config` prints it and exits.

use clap::Args;

use cloudscape_core::world::authored::{Area, Influence, Shape};
use cloudscape_core::world::warm::WarmArea;
use cloudscape_core::world::{Config, ConfigError, DEFAULT_CONFIG, World, WorldClock, read_config_text};
use cloudscape_server::{Server, ServerConfig};

/// Sections whose keys the environment may override.
const ENV_SECTIONS: [&str; 2] = ["server", "limits"];

#[derive(Args)]
pub struct ServeArgs {
    /// Config file (default: $CLOUDSCAPE_CONFIG, else the embedded config).
    #[arg(long)]
    config: Option<String>,
    /// Address to listen on (default: the config's server.listen, 127.0.0.1:8080).
    #[arg(long)]
    listen: Option<String>,
    /// Print the effective configuration as TOML and exit.
    #[arg(long)]
    print_config: bool,
    /// Log lines on stderr: `text` (colour only when stderr is a terminal and NO_COLOR
    /// is unset) or `json` (one object a line, the request's fields flattened in).
    #[arg(long, value_enum, default_value_t = LogFormat::Text)]
    log_format: LogFormat,
}

/// How `serve` writes its log lines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    Text,
    Json,
}

/// Standard error that never fails: a log line that cannot be written (the reader of
/// a stderr pipe went away: EPIPE) is dropped. tracing-subscriber reports a failed
/// write with `eprintln!`, which panics on that same closed pipe, inside whatever
/// task was logging (the shutdown task, a request).
struct LossyStderr;

impl std::io::Write for LossyStderr {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        Ok(std::io::stderr().write(buf).unwrap_or(buf.len()))
    }

    fn flush(&mut self) -> std::io::Result<()> {
        let _ = std::io::stderr().flush();
        Ok(())
    }
}

/// Installs the log subscriber: `RUST_LOG` filter (default `info`), `format`, no
/// ANSI escapes unless stderr is a terminal, writes that cannot fail.
fn init_logging(format: LogFormat) {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let ansi = std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty());
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(|| LossyStderr)
        .log_internal_errors(false);
    let _ = match format {
        LogFormat::Text => builder.with_ansi(ansi).try_init(),
        LogFormat::Json => builder
            .json()
            .flatten_event(true)
            .with_current_span(true)
            .with_span_list(false)
            .try_init(),
    };
}

/// The config text with environment (`vars`) and flag overrides applied, validated.
pub(crate) fn effective_config(
    file: Option<&str>,
    listen: Option<&str>,
    vars: impl IntoIterator<Item = (String, String)>,
) -> Result<(Config, ServerConfig), String> {
    let text = match file {
        Some(p) => read_config_text(p).map_err(|e| e.to_string())?,
        None => DEFAULT_CONFIG.to_string(),
    };
    let mut doc: toml::Table = toml::from_str(&text).map_err(|e| ConfigError::toml(&text, &e).to_string())?;
    let mut set = |section: &str, key: &str, value: toml::Value| -> Result<(), String> {
        let table = doc
            .entry(section)
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        match table {
            toml::Value::Table(t) => {
                t.insert(key.to_string(), value);
                Ok(())
            }
            _ => Err(format!("invalid config: `{section}` must be a table")),
        }
    };
    for (name, raw) in vars {
        let Some(rest) = name.strip_prefix("CLOUDSCAPE_") else {
            continue;
        };
        let Some((section, key)) = ENV_SECTIONS
            .iter()
            .find_map(|s| Some((s, rest.strip_prefix(&format!("{}_", s.to_uppercase()))?)))
        else {
            continue;
        };
        let key = key.to_lowercase();
        let known = known_keys(section)?;
        if !known.contains(&key) {
            return Err(format!(
                "unknown environment variable {name}: [{section}] has no key `{key}` (keys: {})",
                known.join(", ")
            ));
        }
        // TOML syntax when it parses (numbers, booleans, quoted strings), else a plain string.
        let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or(toml::Value::String(raw.clone()));
        set(section, &key, value).map_err(|e| format!("{e} (from {name})"))?;
    }
    if let Some(l) = listen {
        set("server", "listen", toml::Value::String(l.to_string()))?;
    }
    let merged = toml::to_string(&doc).map_err(|e| format!("cannot merge config overrides: {e}"))?;
    let config = Config::parse(&merged).map_err(|e| e.to_string())?;
    let server = ServerConfig::parse(&merged).map_err(|e| e.to_string())?;
    cloudscape_server::check_config(&config, &server).map_err(|e| e.to_string())?;
    Ok((config, server))
}

/// The keys of the `[server]` or `[limits]` section, as the environment may name them.
fn known_keys(section: &str) -> Result<Vec<String>, String> {
    let defaults = match section {
        "server" => value(&ServerConfig::default())?,
        _ => value(&Config::embedded().limits)?,
    };
    Ok(defaults
        .as_table()
        .map(|t| t.keys().cloned().collect())
        .unwrap_or_default())
}

/// The effective configuration as TOML that `Config::parse` reads back to the same config.
pub(crate) fn config_to_toml(config: &Config, server: &ServerConfig) -> Result<String, String> {
    let mut doc = toml::Table::new();
    doc.insert("server".into(), value(server)?);
    doc.insert("limits".into(), value(&config.limits)?);
    doc.insert("sun".into(), value(&config.sun)?);
    doc.insert("presets".into(), value(&config.presets)?);
    let mut worlds = toml::Table::new();
    for (name, w) in &config.worlds {
        let mut layers = Vec::new();
        for l in &w.layers {
            let toml::Value::Table(mut t) = value(l)? else {
                return Err("a layer is not a table".into());
            };
            t.remove("preset_name");
            // The world's freezing level, which every layer carries a copy of.
            t.remove("freezing_level");
            t.insert("preset".into(), toml::Value::String(l.preset_name.clone()));
            if l.ellipsoids.is_empty() {
                t.remove("ellipsoids");
            }
            // A copy of the world's authored weather, printed once below.
            t.remove("authored");
            layers.push(toml::Value::Table(t));
        }
        let mut wt = toml::Table::new();
        wt.insert("seed".into(), toml::Value::Integer(w.seed as i64));
        if let Some(l) = w.layers.first() {
            wt.insert("freezing_level".into(), toml::Value::Float(l.freezing_level));
        }
        wt.insert("layers".into(), toml::Value::Array(layers));
        let (mut events, mut regions) = (Vec::new(), Vec::new());
        for (preset, influence) in &w.authored {
            let (is_region, entry) = authored_entry(preset, influence)?;
            if is_region { &mut regions } else { &mut events }.push(toml::Value::Table(entry));
        }
        for (key, list) in [("events", events), ("regions", regions)] {
            if !list.is_empty() {
                wt.insert(key.into(), toml::Value::Array(list));
            }
        }
        if w.clock != WorldClock::default() {
            wt.insert("clock".into(), value(&w.clock)?);
        }
        let warm: Vec<toml::Value> = w.warm.iter().map(|a| warm_entry(w, a)).collect::<Result<_, _>>()?;
        if !warm.is_empty() {
            wt.insert("warm".into(), toml::Value::Array(warm));
        }
        worlds.insert(name.clone(), toml::Value::Table(wt));
    }
    doc.insert("worlds".into(), toml::Value::Table(worlds));
    toml::to_string(&doc).map_err(|e| format!("cannot print config: {e}"))
}

/// One `[[worlds.NAME.events]]` entry (false) or `[[worlds.NAME.regions]]` entry
/// (true, a region with a one-preset mix) that parses back to `influence` on `preset`.
fn authored_entry(preset: &str, influence: &Influence) -> Result<(bool, toml::Table), String> {
    let mut t = toml::Table::new();
    let mut put = |k: &str, v: toml::Value| {
        t.insert(k.into(), v);
    };
    let is_region = match &influence.shape {
        Shape::Storm(st) => {
            put("kind", "storm".into());
            put("preset", preset.into());
            put("centre", value(&st.centre)?);
            put("radii", value(&st.radii)?);
            if st.path.is_empty() {
                put("velocity", value(&st.velocity)?);
            } else {
                put("path", value(&st.path)?);
            }
            false
        }
        Shape::Front(f) => {
            put("kind", "front".into());
            put("preset", preset.into());
            put("origin", value(&f.origin)?);
            put("velocity", value(&f.velocity)?);
            put("width", f.width.into());
            put("behind", f.behind.into());
            if let Some(l) = f.length {
                put("length", l.into());
            }
            false
        }
        Shape::Region { area, blend } => {
            match area {
                Area::Box(b) => put("box", value(b)?),
                Area::Polygon(p) => put("polygon", value(p)?),
            }
            put("blend", (*blend).into());
            let mut mix = toml::Table::new();
            mix.insert(preset.into(), influence.intensity.into());
            put("mix", toml::Value::Table(mix));
            true
        }
    };
    if !is_region {
        put("intensity", influence.intensity.into());
    }
    if let Some(start) = influence.start {
        put("start", start.into());
    }
    if let Some(end) = influence.end {
        put("end", end.into());
    }
    put("ramp", influence.ramp.into());
    Ok((is_region, t))
}

/// One `[[worlds.NAME.warm]]` entry that parses back to `area` of world `w`.
fn warm_entry(w: &World, area: &WarmArea) -> Result<toml::Value, String> {
    let mut t = toml::Table::new();
    t.insert("name".into(), area.name.clone().into());
    match &area.area {
        Area::Box(b) => t.insert("bbox".into(), value(b)?),
        Area::Polygon(p) => t.insert("polygon".into(), value(p)?),
    };
    t.insert("margin".into(), value(&area.margin)?);
    t.insert("levels".into(), value(&area.levels)?);
    t.insert("products".into(), value(&area.products)?);
    t.insert("qualities".into(), value(&area.qualities)?);
    let layers: Vec<&str> = area.layers.iter().map(|&l| w.layers[l].name.as_str()).collect();
    t.insert("layers".into(), value(&layers)?);
    Ok(toml::Value::Table(t))
}

fn value<T: serde::Serialize>(v: &T) -> Result<toml::Value, String> {
    toml::Value::try_from(v).map_err(|e| format!("cannot print config: {e}"))
}

pub fn run(a: ServeArgs) -> Result<(), String> {
    let file = a.config.or_else(|| std::env::var("CLOUDSCAPE_CONFIG").ok());
    let (config, settings) = effective_config(file.as_deref(), a.listen.as_deref(), std::env::vars())?;
    if a.print_config {
        print!("{}", config_to_toml(&config, &settings)?);
        return Ok(());
    }
    init_logging(a.log_format);
    // A panic is one log line, never a backtrace a client could have written per request.
    cloudscape_server::log_panics_in_one_line();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the async runtime: {e}"))?;
    runtime.block_on(async move {
        let listen = settings.listen.clone();
        let server = Server::bind(config, settings).await.map_err(|e| match e.kind() {
            std::io::ErrorKind::InvalidInput => e.to_string(),
            _ => format!("cannot listen on {listen}: {e}"),
        })?;
        let addr = server.local_addr().map_err(|e| e.to_string())?;
        tracing::info!(%addr, "listening on http://{addr}");
        let shutdown = server.shutdown_handle();
        tokio::spawn(async move {
            termination_signal().await;
            // Trigger before logging: a log write may block (a full or closed stderr
            // pipe) and must not hold the shutdown back.
            shutdown.trigger();
            tracing::info!("signal received: shutting down gracefully");
        });
        server.run().await.map_err(|e| format!("server failed: {e}"))
    })
}

/// Ctrl-C or SIGTERM.
async fn termination_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = term => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn printed_config_reads_back_equal() {
        let (c, s) = (Config::embedded(), ServerConfig::embedded());
        let text = config_to_toml(&c, &s).unwrap();
        assert_eq!(Config::parse(&text).unwrap(), c);
        assert_eq!(ServerConfig::parse(&text).unwrap(), s);
        // Authored weather of every form: a storm on a path, a region of two presets.
        let more = format!(
            "{DEFAULT_CONFIG}\n[[worlds.storm-front.events]]\nkind = \"storm\"\npreset = \"cumulonimbus\"\n\
             centre = [0.0, 0.0, 3000.0]\nradii = [1000.0, 1000.0, 1000.0]\npath = [[0.0, 0.0, 0.0], [100.0, 50.0, 0.0]]\n\
             [[worlds.storm-front.regions]]\nbox = [0.0, 0.0, 10.0, 10.0]\nmix = {{ cumulonimbus = 0.5, stratocumulus = -0.5 }}\nend = 500.0\n"
        );
        let more = format!(
            "{more}[worlds.storm-front.clock]\noffset = -1.0e9\nrate = 12.0\n\
             [[worlds.storm-front.warm]]\nname = \"camp\"\npolygon = [[0.0, 0.0], [5000.0, 0.0], [0.0, 5000.0]]\n\
             levels = [0, 3]\nproducts = [\"density.u8\"]\nlayers = [\"anvil\"]\nmargin = 100.0\n\
             [[worlds.storm-front.warm]]\nname = \"ridge\"\nbbox = [0.0, 0.0, 10.0, 10.0]\nmargin = \"view\"\n"
        );
        let c = Config::parse(&more).unwrap();
        assert_eq!(c.worlds["storm-front"].authored.len(), 3);
        assert_eq!(c.worlds["storm-front"].clock.rate, 12.0);
        assert_eq!(c.worlds["storm-front"].warm.len(), 2);
        let text = config_to_toml(&c, &s).unwrap();
        assert_eq!(Config::parse(&text).unwrap(), c);
        assert!(!c.worlds["archipelago"].authored.is_empty());
    }

    #[test]
    fn environment_and_flags_override_in_order() {
        let vars = vec![
            ("CLOUDSCAPE_SERVER_LISTEN".to_string(), "0.0.0.0:9000".to_string()),
            ("CLOUDSCAPE_SERVER_CACHE_BYTES".to_string(), "1234".to_string()),
            ("CLOUDSCAPE_LIMITS_MAX_LEVEL".to_string(), "7".to_string()),
            ("UNRELATED".to_string(), "x".to_string()),
        ];
        let (c, s) = effective_config(None, None, vars.clone()).unwrap();
        assert_eq!(s.listen, "0.0.0.0:9000");
        assert_eq!(s.cache_bytes, 1234);
        assert_eq!(c.limits.max_level, 7);
        let (_, s) = effective_config(None, Some("127.0.0.1:1"), vars).unwrap();
        assert_eq!(s.listen, "127.0.0.1:1");
        let redis = vec![(
            "CLOUDSCAPE_SERVER_REDIS_URL".to_string(),
            "redis://10.0.0.5:6379/2".to_string(),
        )];
        let (_, s) = effective_config(None, None, redis).unwrap();
        assert_eq!(s.redis_url, "redis://10.0.0.5:6379/2");
        assert_eq!(ServerConfig::embedded().redis_url, "", "no Redis unless configured");
    }

    #[test]
    fn unknown_or_invalid_overrides_are_named() {
        let refused =
            |name: &str, value: &str| effective_config(None, None, vec![(name.into(), value.into())]).unwrap_err();
        // An unknown name is named, with the keys it may have meant.
        for (name, value, meant) in [
            ("CLOUDSCAPE_SERVER_BOGUS", "1", &["`bogus`", "cors_origins"][..]),
            ("CLOUDSCAPE_LIMITS_MAX_LEVLE", "3", &["max_level"]),
        ] {
            let e = refused(name, value);
            assert!(e.starts_with(&format!("unknown environment variable {name}:")), "{e}");
            assert!(meant.iter().all(|key| e.contains(key)), "{e}");
        }
        let e = refused("CLOUDSCAPE_SERVER_FRAMES_PER_STEP", "0");
        assert!(e.contains("frames_per_step"), "{e}");
        let e = refused("CLOUDSCAPE_SERVER_REDIS_URL", "http://cache:6379");
        assert!(e.contains("redis_url"), "{e}");
    }
}
