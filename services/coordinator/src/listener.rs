//! The gRPC listener's limits: how many connections it holds at once and how long a connection
//! may stay silent before its first bytes, so that clients that connect and never speak (a
//! slowloris) cannot take every connection. A connection past the cap is closed at once; one
//! that sends nothing within `FIRST_BYTES_TIMEOUT` is closed then (a TLS client gets
//! `HANDSHAKE_TIMEOUT` for its whole handshake, `tls.rs`). HTTP/2 keepalive pings (`lib.rs`)
//! close connections whose peer went away.

use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use futures::{Stream, StreamExt};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tonic::transport::server::{Connected, TcpConnectInfo};

/// Longest a TLS handshake may take.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// Longest a new connection may stay silent before it sends its first bytes (the HTTP/2
/// preface, or a TLS hello).
pub const FIRST_BYTES_TIMEOUT: Duration = Duration::from_secs(10);

/// `incoming`'s connections, at most `max` open at once, each closed if silent for `silent_for`
/// after it opened.
pub fn capped(
    incoming: impl Stream<Item = std::io::Result<TcpStream>>,
    max: usize,
    silent_for: Duration,
) -> impl Stream<Item = std::io::Result<Capped>> {
    let open = Arc::new(Semaphore::new(max));
    incoming.filter_map(move |accepted| {
        let open = open.clone();
        async move {
            let io = match accepted {
                Ok(io) => io,
                Err(e) => return Some(Err(e)),
            };
            match open.try_acquire_owned() {
                Ok(permit) => Some(Ok(Capped {
                    io,
                    _permit: permit,
                    silence: Some(Box::pin(tokio::time::sleep(silent_for))),
                })),
                Err(_) => {
                    tracing::warn!(max, peer = ?io.peer_addr().ok(), "gRPC connection closed: at the connection limit (--max-connections)");
                    None
                }
            }
        }
    })
}

/// A connection that holds one of the listener's places until it is dropped, and fails its
/// reads once silent past its deadline before its first bytes.
pub struct Capped {
    io: TcpStream,
    _permit: OwnedSemaphorePermit,
    /// Until the first bytes arrive: when the connection is given up.
    silence: Option<Pin<Box<tokio::time::Sleep>>>,
}

impl AsyncRead for Capped {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let read = Pin::new(&mut this.io).poll_read(cx, buf);
        let Some(silence) = this.silence.as_mut() else { return read };
        match read {
            Poll::Ready(Ok(())) if buf.filled().len() > before => this.silence = None,
            Poll::Pending if silence.as_mut().poll(cx).is_ready() => {
                return Poll::Ready(Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    "the client sent nothing in time after connecting",
                )));
            }
            _ => {}
        }
        read
    }
}

impl AsyncWrite for Capped {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.get_mut().io).poll_write(cx, buf)
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.get_mut().io).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }
}

impl Connected for Capped {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> TcpConnectInfo {
        self.io.connect_info()
    }
}

#[cfg(test)]
mod tests {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpListener;

    use super::*;

    /// Accepts through `capped` and echoes each connection's bytes until it fails.
    async fn echo_server(max: usize, silent_for: Duration) -> std::net::SocketAddr {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let incoming = tonic::transport::server::TcpIncoming::from(listener);
        let mut conns = Box::pin(capped(incoming, max, silent_for));
        tokio::spawn(async move {
            while let Some(Ok(mut conn)) = conns.next().await {
                tokio::spawn(async move {
                    let mut buf = [0u8; 64];
                    while let Ok(n) = conn.read(&mut buf).await {
                        if n == 0 || conn.write_all(&buf[..n]).await.is_err() {
                            break;
                        }
                    }
                });
            }
        });
        addr
    }

    #[tokio::test]
    async fn a_silent_connection_is_closed_and_its_place_freed_and_none_past_the_cap_is_held() {
        let addr = echo_server(1, Duration::from_millis(300)).await;
        let mut silent = TcpStream::connect(addr).await.unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
        // The one place is held: the next connection is closed without an echo.
        let mut refused = TcpStream::connect(addr).await.unwrap();
        let _ = refused.write_all(b"x").await;
        let mut got = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(5), refused.read_to_end(&mut got)).await.unwrap();
        assert!(got.is_empty(), "a connection past the cap was served");
        // The silent one is closed after its deadline, and its place serves a talking client.
        let mut rest = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(5), silent.read_to_end(&mut rest)).await.unwrap();
        let mut talker = TcpStream::connect(addr).await.unwrap();
        talker.write_all(b"ping").await.unwrap();
        let mut echo = [0u8; 4];
        tokio::time::timeout(Duration::from_secs(5), talker.read_exact(&mut echo)).await.unwrap().unwrap();
        assert_eq!(&echo, b"ping");
        // Once it has spoken, the deadline no longer applies.
        tokio::time::sleep(Duration::from_millis(500)).await;
        talker.write_all(b"pong").await.unwrap();
        tokio::time::timeout(Duration::from_secs(5), talker.read_exact(&mut echo)).await.unwrap().unwrap();
        assert_eq!(&echo, b"pong");
    }
}
