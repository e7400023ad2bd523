//! A deliberately small HTTP/1.1 client over a plain TCP socket: it writes whatever
//! bytes it is given (invalid UTF-8, header floods — things a real client library
//! refuses to send) and reads one answer, keeping the connection alive when it can.

use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::time::Duration;

/// Bytes of a body kept for inspection; the rest is read and counted.
pub const KEPT_BODY_BYTES: usize = 64 * 1024;

/// One HTTP answer.
#[derive(Clone, Debug)]
pub struct Answer {
    pub status: u16,
    /// Header names lower-cased.
    pub headers: Vec<(String, String)>,
    /// The first [`KEPT_BODY_BYTES`] of the body.
    pub body: Vec<u8>,
    pub body_len: u64,
}

impl Answer {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }
}

/// How an exchange failed.
#[derive(Debug)]
pub enum Failure {
    /// The connection was closed (or reset) before an answer arrived.
    Closed(io::Error),
    /// Nothing arrived within the socket timeout.
    TimedOut,
    /// Something arrived that is not HTTP/1.1.
    Garbled(String),
}

/// A keep-alive connection to one server.
pub struct Connection {
    reader: BufReader<TcpStream>,
    /// Exchanges done on this connection: a failure on a reused connection may just be
    /// the server closing an idle keep-alive connection.
    pub used: u64,
}

impl Connection {
    pub fn open(addr: &str, timeout: Duration) -> io::Result<Connection> {
        let stream = TcpStream::connect(addr)?;
        stream.set_read_timeout(Some(timeout))?;
        stream.set_write_timeout(Some(timeout))?;
        stream.set_nodelay(true)?;
        Ok(Connection {
            reader: BufReader::with_capacity(64 * 1024, stream),
            used: 0,
        })
    }

    /// Writes `request` and reads one answer. `head` tells that the request was a HEAD
    /// (its answer has no body). Returns the answer and whether the connection may be
    /// reused.
    pub fn exchange(&mut self, request: &[u8], head: bool) -> Result<(Answer, bool), Failure> {
        self.used += 1;
        // A server may answer (431, 400) and close before reading all of a huge
        // request: a failed write is not yet a failed exchange.
        let write = self.reader.get_mut().write_all(request);
        let answer = self.read_answer(head);
        match (answer, write) {
            (Ok(a), _) => Ok(a),
            (Err(e), Err(w)) if !matches!(e, Failure::TimedOut) => Err(Failure::Closed(w)),
            (Err(e), _) => Err(e),
        }
    }

    fn read_answer(&mut self, head: bool) -> Result<(Answer, bool), Failure> {
        let status_line = self.line()?;
        let mut parts = status_line.splitn(3, ' ');
        let version = parts.next().unwrap_or("");
        let status: u16 = parts
            .next()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| Failure::Garbled(format!("status line `{status_line}`")))?;
        if !version.starts_with("HTTP/1.") {
            return Err(Failure::Garbled(format!("status line `{status_line}`")));
        }
        let mut headers = Vec::new();
        loop {
            let line = self.line()?;
            if line.is_empty() {
                break;
            }
            if headers.len() > 200 {
                return Err(Failure::Garbled("more than 200 header lines".into()));
            }
            if let Some((k, v)) = line.split_once(':') {
                headers.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
            }
        }
        let mut answer = Answer {
            status,
            headers,
            body: Vec::new(),
            body_len: 0,
        };
        let mut keep = !answer
            .header("connection")
            .is_some_and(|c| c.eq_ignore_ascii_case("close"));
        if head || status == 204 || status == 304 || (100..200).contains(&status) {
            return Ok((answer, keep));
        }
        if answer
            .header("transfer-encoding")
            .is_some_and(|t| t.to_ascii_lowercase().contains("chunked"))
        {
            loop {
                let size_line = self.line()?;
                let size = u64::from_str_radix(size_line.split(';').next().unwrap_or("").trim(), 16)
                    .map_err(|_| Failure::Garbled(format!("chunk size `{size_line}`")))?;
                if size == 0 {
                    // Trailers, then the blank line.
                    while !self.line()?.is_empty() {}
                    break;
                }
                self.body(size, &mut answer)?;
                self.line()?;
            }
        } else if let Some(len) = answer.header("content-length") {
            let len: u64 = len
                .parse()
                .map_err(|_| Failure::Garbled(format!("content-length `{len}`")))?;
            self.body(len, &mut answer)?;
        } else {
            // No length: the body runs to the end of the connection.
            let mut rest = Vec::new();
            self.reader
                .by_ref()
                .take(1 << 30)
                .read_to_end(&mut rest)
                .map_err(io_failure)?;
            answer.body_len = rest.len() as u64;
            rest.truncate(KEPT_BODY_BYTES);
            answer.body = rest;
            keep = false;
        }
        Ok((answer, keep))
    }

    fn body(&mut self, len: u64, answer: &mut Answer) -> Result<(), Failure> {
        let keep = (KEPT_BODY_BYTES.saturating_sub(answer.body.len()) as u64).min(len);
        let mut kept = vec![0; keep as usize];
        self.reader.read_exact(&mut kept).map_err(io_failure)?;
        answer.body.extend_from_slice(&kept);
        let skipped = io::copy(&mut self.reader.by_ref().take(len - keep), &mut io::sink()).map_err(io_failure)?;
        if skipped != len - keep {
            return Err(Failure::Closed(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "body cut short",
            )));
        }
        answer.body_len += len;
        Ok(())
    }

    /// One CRLF-terminated line (at most 64 KiB), without the terminator.
    fn line(&mut self) -> Result<String, Failure> {
        let mut buf = Vec::new();
        let n = self
            .reader
            .by_ref()
            .take(64 * 1024)
            .read_until(b'\n', &mut buf)
            .map_err(io_failure)?;
        if n == 0 {
            return Err(Failure::Closed(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "connection closed",
            )));
        }
        if buf.last() != Some(&b'\n') {
            return Err(Failure::Garbled("a line longer than 64 KiB".into()));
        }
        while matches!(buf.last(), Some(b'\n' | b'\r')) {
            buf.pop();
        }
        Ok(String::from_utf8_lossy(&buf).into_owned())
    }
}

fn io_failure(e: io::Error) -> Failure {
    match e.kind() {
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut => Failure::TimedOut,
        _ => Failure::Closed(e),
    }
}

/// Host and port of an `http://HOST:PORT[/]` URL.
pub fn host_port(url: &str) -> Result<String, String> {
    let rest = url
        .strip_prefix("http://")
        .ok_or_else(|| format!("the target must be an http:// URL, got `{url}`"))?;
    let host = rest.trim_end_matches('/');
    if host.is_empty() || host.contains('/') {
        return Err(format!("the target must be http://HOST:PORT, got `{url}`"));
    }
    Ok(if host.contains(':') {
        host.to_string()
    } else {
        format!("{host}:80")
    })
}
