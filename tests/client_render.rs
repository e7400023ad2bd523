//! The Rust client against a real server: a remote render (`client::TileClient`,
//! `cloudscape render --server URL`) is the local render of the same scene pixel for
//! pixel (both draw the same served keyframes the same way, `cloudscape_core::view`);
//! a second render takes every keyframe from memory; the async client
//! (`client::AsyncTileClient`) draws the same pixels as the blocking one; a client
//! animating past a keyframe fetches the next one as a delta and still draws the
//! server's picture.

mod common;

use std::net::SocketAddr;
use std::process::Command;
use std::sync::mpsc;

use cloudscape_client::{AsyncTileClient, ClientError, TileClient};
use cloudscape_core::render::{Camera, Quality, RenderRequest, ShadingParams};
use cloudscape_core::view::render;
use cloudscape_core::world::Config;
use cloudscape_server::{Server, ServerConfig, ShutdownHandle};

struct RunningServer {
    base: String,
    shutdown: ShutdownHandle,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Drop for RunningServer {
    fn drop(&mut self) {
        self.shutdown.trigger();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// `cloudscape serve` on the embedded config, in-process on 127.0.0.1:0.
fn start_server() -> RunningServer {
    let config = Config::embedded();
    let settings = ServerConfig {
        listen: "127.0.0.1:0".to_string(),
        request_timeout_ms: 600_000,
        drain_ms: 0,
        ..ServerConfig::embedded()
    };
    let (tx, rx) = mpsc::channel::<(SocketAddr, ShutdownHandle)>();
    let thread = std::thread::spawn(move || {
        let runtime = tokio::runtime::Runtime::new().expect("tokio runtime");
        runtime.block_on(async move {
            let server = Server::bind(config, settings).await.expect("bind 127.0.0.1:0");
            tx.send((server.local_addr().unwrap(), server.shutdown_handle()))
                .unwrap();
            server.run().await.expect("server runs");
        });
    });
    let (addr, shutdown) = rx.recv().expect("the server starts");
    RunningServer {
        base: format!("http://{addr}"),
        shutdown,
        thread: Some(thread),
    }
}

/// Mean and max absolute difference of two images' display values.
fn difference(a: &[[f32; 3]], b: &[[f32; 3]]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for (p, q) in a.iter().zip(b) {
        for c in 0..3 {
            let d = (p[c] - q[c]).abs() as f64;
            sum += d;
            max = max.max(d);
        }
    }
    (sum / (3 * a.len()) as f64, max)
}

fn decode_png(path: &std::path::Path) -> (u32, u32, Vec<u8>) {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn a_remote_render_matches_a_local_one_and_revalidates() {
    let server = start_server();
    let config = Config::embedded();
    let world = config.world("default").unwrap();
    // Between the altocumulus top (5 km) and the cirrus base (8 km), looking down and
    // north: the two lower layers, several tiles and levels, sunlit ground.
    let req = looking_down(192, 108);
    let local = render(&world, &config, &req).expect("local render");
    let mut client = TileClient::new(&server.base).unwrap();
    let remote = client.render("default", &req).expect("remote render");

    assert!(!local.tiles.is_empty() && local.billboards > 0, "the scene has clouds");
    assert_eq!(remote.tiles, local.tiles, "the same level choice");
    assert_eq!(remote.billboards, local.billboards, "every billboard served");
    assert_eq!(
        remote.sun,
        local.sun.bucket().centre(),
        "the centre of the clock sun's bucket"
    );
    assert_eq!(remote.image.display(), local.image.display(), "the same pixels");

    // One keyframe per tile and the world: all 200s. At a keyframe's own time nothing
    // is past the middle of its span: no prefetch.
    let first = client.stats();
    assert_eq!((first.revalidated, first.reused, first.prefetched), (0, 0, 0));
    assert_eq!(first.fetched as usize, local.tiles.len() + 1);
    // Again with the same client: the keyframes are held, so they come from memory
    // without a request; only the world is revalidated.
    let again = client.render("default", &req).expect("second remote render");
    let second = client.stats();
    assert_eq!(second.fetched, first.fetched, "nothing downloaded again");
    assert_eq!(second.body_bytes, first.body_bytes);
    assert_eq!(second.reused, first.fetched - 1, "keyframes reused without asking");
    assert_eq!(second.revalidated, 1, "the world document revalidated with a 304");
    assert_eq!(second.requests, first.requests + 1);
    assert_eq!(again.image.display(), remote.image.display());

    // The command line: `render --server` writes the same picture as a local render.
    let dir = tempfile::tempdir().unwrap();
    let (remote_png, local_png) = (dir.path().join("remote.png"), dir.path().join("local.png"));
    let args = [
        "render",
        "--world",
        "default",
        "--camera",
        "12800,6000,7000,0,-50,70",
        "--t",
        "43200",
        "--size",
        "96x54",
        "--quality",
        "fast",
    ];
    let bin = env!("CARGO_BIN_EXE_cloudscape");
    let out = Command::new(bin)
        .args(args)
        .args(["--server", server.base.as_str(), "--out"])
        .arg(&remote_png)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = Command::new(bin)
        .args(args)
        .arg("--out")
        .arg(&local_png)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (w, h, a) = decode_png(&remote_png);
    let (w2, h2, b) = decode_png(&local_png);
    assert_eq!((w, h), (w2, h2));
    assert_eq!((w, h), (96, 54));
    assert!(a == b, "the CLI's remote and local pictures are the same pixels");
}

#[test]
fn the_async_client_draws_the_blocking_clients_pixels_and_revalidates() {
    let server = start_server();
    let req = looking_down(96, 54);
    let mut blocking = TileClient::new(&server.base).unwrap();
    let expected = blocking.render("default", &req).expect("blocking render");

    // The blocking client may not run inside a runtime, so the async one gets its own.
    let runtime = tokio::runtime::Runtime::new().expect("tokio runtime");
    let (first, first_stats, again, second_stats) = runtime.block_on(async {
        let mut client = AsyncTileClient::new(&server.base).unwrap();
        let first = client.render("default", &req).await.expect("async render");
        let first_stats = client.stats();
        let again = client.render("default", &req).await.expect("second async render");
        (first, first_stats, again, client.stats())
    });

    assert!(expected.billboards > 0, "the scene has clouds");
    assert_eq!(first.tiles, expected.tiles, "the same level choice");
    assert_eq!(first.billboards, expected.billboards);
    assert_eq!(first.sun, expected.sun);
    assert_eq!(first.image.display(), expected.image.display(), "identical pixels");
    assert_eq!(first_stats.fetched, blocking.stats().fetched, "the same bodies");
    assert_eq!(first_stats.body_bytes, blocking.stats().body_bytes);
    assert_eq!(first_stats.revalidated, 0);

    // The same view again: immutable bodies from memory, the world revalidated.
    assert_eq!(second_stats.fetched, first_stats.fetched, "nothing downloaded again");
    assert_eq!(second_stats.body_bytes, first_stats.body_bytes);
    assert_eq!(second_stats.reused, first_stats.fetched - 1);
    assert_eq!(second_stats.revalidated, 1);
    assert_eq!(again.image.display(), expected.image.display());
}

#[test]
fn between_keyframes_the_client_draws_the_servers_picture_and_prefetches() {
    // Three quarters into the level-0 keyframe span [43200, 43220): the client applies
    // the animation rule to the keyframe it fetched, the server's renderer too.
    let server = start_server();
    let config = Config::embedded();
    let world = config.world("default").unwrap();
    let req = RenderRequest {
        t: 43_215.0,
        ..looking_down(192, 108)
    };
    let local = render(&world, &config, &req).expect("local render");
    let mut client = TileClient::new(&server.base).unwrap();
    let remote = client.render("default", &req).expect("remote render");
    assert_eq!(remote.tiles, local.tiles);
    assert_eq!(remote.image.display(), local.image.display(), "between keyframes too");
    // The picture moved on from the keyframe: it is not the keyframe's own.
    let at_keyframe = render(&world, &config, &RenderRequest { t: 43_200.0, ..req }).unwrap();
    let (moved, _) = difference(&at_keyframe.image.display(), &local.image.display());
    assert!(moved > 1.0 / 255.0, "the clouds moved: {moved:.5}");
    // Past the middle of every level-0 span: the next keyframes were fetched ahead,
    // and drawing the next keyframe's time needs no tile request.
    let stats = client.stats();
    assert!(stats.prefetched > 0, "{stats:?}");
    let before = client.stats().requests;
    let level0 = local.tiles.iter().filter(|(_, t)| t.z == 0).count();
    assert!(level0 > 0, "the view holds level-0 tiles");
    let next = client
        .render("default", &RenderRequest { t: 43_220.0, ..req })
        .expect("render at the next keyframe");
    let after = client.stats();
    // Level 0 changed keyframe and was prefetched; coarser levels' spans ([43200,
    // 43240) and longer) hold 43 220 too. So only the world is asked again, besides
    // the prefetches of this render (spans now half gone).
    let prefetched = after.prefetched - stats.prefetched;
    assert_eq!(after.requests - before - prefetched, 1, "{after:?}");
    assert!(after.reused >= stats.reused + local.tiles.len() as u64, "{after:?}");
    // The prefetched keyframes were deltas on those held, and draw the server's picture.
    let local_next = render(&world, &config, &RenderRequest { t: 43_220.0, ..req }).unwrap();
    assert_eq!(next.image.display(), local_next.image.display(), "drawn from deltas");
}

#[test]
fn remote_errors_are_one_clear_sentence() {
    // Nothing listens on a port we just released.
    let url = format!("http://127.0.0.1:{}", common::free_port());
    let mut client = TileClient::new(&url).unwrap();
    assert!(matches!(client.world("default"), Err(ClientError::Transport { .. })));

    let out = render_remote(&url, "/dev/null/never.png");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(stderr.contains(&url), "{stderr}");

    let out = render_remote("localhost:1", "x.png");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("http://HOST:PORT"));
}

/// `cloudscape render --server URL` of a small view of the default world.
fn render_remote(url: &str, out: &str) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["render", "--world", "default", "--camera", "0,0,900,0,5,60"])
        .args(["--t", "0", "--size", "8x8", "--server", url, "--out", out])
        .output()
        .unwrap()
}

#[test]
fn an_unknown_remote_world_is_the_servers_404() {
    let server = start_server();
    let mut client = TileClient::new(&server.base).unwrap();
    match client.world("nope") {
        Err(ClientError::Status { status, message, .. }) => {
            assert_eq!(status, 404);
            assert!(message.contains("nope"), "{message}");
        }
        other => panic!("expected a 404, got {other:?}", other = other.map(|w| w.name)),
    }
}

/// Between the altocumulus top (5 km) and the cirrus base (8 km), looking down and
/// north at noon, `fast`: the two lower layers, several tiles and levels, sunlit ground.
fn looking_down(width: usize, height: usize) -> RenderRequest {
    RenderRequest {
        camera: Camera::parse("12800,6000,7000,0,-50,70").unwrap(),
        width,
        height,
        t: 43200.0,
        quality: Quality::Fast,
        sun: None,
        params: ShadingParams::default(),
        samples: 32,
    }
}
