//! Keyed links: a Noise handshake with a pre-shared key, then every byte of
//! the framed stream inside Noise transport messages.
//!
//! The pattern is `Noise_NNpsk0_25519_ChaChaPoly_BLAKE2s`: both ends hold
//! the same 32-byte key ([`Key`], read from a key file), and each
//! connection gets fresh ephemeral keys, so recorded traffic cannot be
//! decrypted later with the key, nor replayed.
//!
//! On the wire every message is a 2-byte big-endian length and that many
//! bytes (at most 65 535). The initiator (the client) sends the first
//! handshake message, the responder (the listener) answers with the second,
//! and the initiator then sends a transport message (empty) that proves it
//! holds the ephemeral key of this session. The listener sends nothing
//! until the first message has been checked against the key, and gives the
//! connection a link only after the proof: a peer without the key sees the
//! socket close without a byte, and one that replays a recorded first
//! message gets only an answer it cannot use.

use super::stream::link_error;
use crate::HostError;
use std::fmt;
use std::io;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, DuplexStream};
use tokio::task::JoinHandle;

/// The Noise protocol of keyed links.
const PATTERN: &str = "Noise_NNpsk0_25519_ChaChaPoly_BLAKE2s";
/// Mixed into the handshake, so a key made for something else, or another
/// version of this protocol, cannot complete it.
const PROLOGUE: &[u8] = b"osap-rs link v1";
/// Longest Noise message.
pub const MAX_MESSAGE: usize = 65_535;
/// Authentication tag of each encrypted message.
const TAG: usize = 16;
/// Longest handshake message accepted (ours are 48 bytes): a larger
/// length is refused before reading it.
const MAX_HANDSHAKE: usize = 256;
/// Bytes buffered between the framed stream and the encrypting task.
const PIPE: usize = 64 * 1024;
/// How long a handshake may take, by default.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);

/// Why a key file's text is not a key ([`Key::parse`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum KeyError {
    /// The text does not hold exactly one line that is not a comment.
    #[error("a key file holds exactly one line of 64 hex digits")]
    LineCount,
    /// The key line is not 64 ASCII characters long; the number is its
    /// length in characters.
    #[error("the key is {0} characters long, not 64 hex digits")]
    Length(usize),
    /// Two characters of the key line are not a hex digit pair.
    #[error(
        "\"{}{}\" at position {position} is not a hex digit pair",
        char::from(pair[0]),
        char::from(pair[1])
    )]
    NotHex {
        /// The two characters (ASCII).
        pair: [u8; 2],
        /// Their position in the line, in characters.
        position: usize,
    },
}

/// A link key: 32 secret bytes that both ends of a keyed link hold.
#[derive(Clone, PartialEq, Eq)]
pub struct Key([u8; 32]);

impl fmt::Debug for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Never print the secret.
        f.write_str("Key(..)")
    }
}

impl Key {
    /// A key from its bytes.
    pub fn from_bytes(bytes: [u8; 32]) -> Key {
        Key(bytes)
    }

    /// A fresh random key from the operating system's generator.
    pub fn generate() -> Result<Key, HostError> {
        let mut bytes = [0u8; 32];
        getrandom::fill(&mut bytes).map_err(|e| {
            link_error(
                "making a key".into(),
                io::ErrorKind::Other,
                format!("the system's random generator failed: {e}"),
            )
        })?;
        Ok(Key(bytes))
    }

    /// The key file's text: a comment line, then the key as 64 hex digits.
    pub fn to_file_text(&self) -> String {
        let hex: String = self.0.iter().map(|b| format!("{b:02x}")).collect();
        format!(
            "# osap link key: keep it secret (chmod 600); both ends need the same file\n{hex}\n"
        )
    }

    /// Parses a key file's text: lines starting with `#` and blank lines
    /// are skipped, the one other line is 64 hex digits.
    pub fn parse(text: &str) -> Result<Key, KeyError> {
        let mut lines = text
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'));
        let (Some(line), None) = (lines.next(), lines.next()) else {
            return Err(KeyError::LineCount);
        };
        if line.len() != 64 || !line.is_ascii() {
            return Err(KeyError::Length(line.chars().count()));
        }
        let mut bytes = [0u8; 32];
        for (i, b) in bytes.iter_mut().enumerate() {
            let pair = line.get(2 * i..2 * i + 2).unwrap_or("");
            *b = u8::from_str_radix(pair, 16).map_err(|_| KeyError::NotHex {
                pair: [pair.as_bytes()[0], pair.as_bytes()[1]],
                position: 2 * i,
            })?;
        }
        Ok(Key(bytes))
    }

    /// Reads a key file, refusing one that others may read: on unix its
    /// mode must give nothing to group or others (`chmod 600 FILE`).
    pub fn load(path: &Path) -> Result<Key, HostError> {
        let context = || format!("reading the key file {}", path.display());
        let meta = std::fs::metadata(path).map_err(|source| HostError::Io {
            context: context(),
            source,
        })?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = meta.permissions().mode() & 0o777;
            if mode & 0o077 != 0 {
                return Err(link_error(
                    context(),
                    io::ErrorKind::PermissionDenied,
                    format!(
                        "it is readable by others (mode {mode:03o}): anyone who can read it can \
                         drive the machine; run chmod 600 {}",
                        path.display()
                    ),
                ));
            }
        }
        #[cfg(not(unix))]
        let _ = meta;
        let text = std::fs::read_to_string(path).map_err(|source| HostError::Io {
            context: context(),
            source,
        })?;
        Key::parse(&text)
            .map_err(|e| link_error(context(), io::ErrorKind::InvalidData, e.to_string()))
    }

    /// Makes a new key and writes it to `path`, readable by its owner only.
    /// Refuses to overwrite an existing file (a key in use would be lost).
    pub fn write_new(path: &Path) -> Result<Key, HostError> {
        let key = Key::generate()?;
        let mut options = std::fs::OpenOptions::new();
        options.write(true).create_new(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            options.mode(0o600);
        }
        let context = || format!("writing the key file {}", path.display());
        let mut file = options.open(path).map_err(|source| {
            let source = if source.kind() == io::ErrorKind::AlreadyExists {
                io::Error::new(
                    source.kind(),
                    "the file exists; remove it first if you mean to replace that key",
                )
            } else {
                source
            };
            HostError::Io {
                context: context(),
                source,
            }
        })?;
        io::Write::write_all(&mut file, key.to_file_text().as_bytes()).map_err(|source| {
            HostError::Io {
                context: context(),
                source,
            }
        })?;
        Ok(key)
    }

    fn builder(&self) -> Result<snow::Builder<'_>, snow::Error> {
        let params: snow::params::NoiseParams = PATTERN.parse()?;
        snow::Builder::new(params)
            .prologue(PROLOGUE)?
            .psk(0, &self.0)
    }
}

/// An error of the handshake or of a session, with what was being done.
fn noise_error(what: &str, why: impl fmt::Display) -> io::Error {
    io::Error::new(io::ErrorKind::PermissionDenied, format!("{what}: {why}"))
}

/// Reads one length-prefixed message of at most `max` bytes into `buf`.
async fn read_message<R: AsyncRead + Unpin>(
    reader: &mut R,
    buf: &mut [u8],
    max: usize,
) -> io::Result<usize> {
    let mut len = [0u8; 2];
    reader.read_exact(&mut len).await?;
    let len = usize::from(u16::from_be_bytes(len));
    if len > max || len < TAG {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("a message of {len} bytes (allowed: {TAG} to {max})"),
        ));
    }
    let msg = buf
        .get_mut(..len)
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidData, "message too long"))?;
    reader.read_exact(msg).await?;
    Ok(len)
}

/// Writes `msg` with its length prefix, in one write.
async fn write_message<W: AsyncWrite + Unpin>(writer: &mut W, msg: &[u8]) -> io::Result<()> {
    let len = u16::try_from(msg.len())
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "message too long"))?;
    let mut out = Vec::with_capacity(msg.len() + 2);
    out.extend_from_slice(&len.to_be_bytes());
    out.extend_from_slice(msg);
    writer.write_all(&out).await
}

/// A byte stream inside a Noise session: what is written is encrypted
/// onto the socket, what is read was decrypted from it. A task moves the
/// bytes; dropping the stream stops it and closes the socket.
#[derive(Debug)]
pub struct NoiseStream {
    pipe: DuplexStream,
    task: JoinHandle<()>,
}

impl Drop for NoiseStream {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl AsyncRead for NoiseStream {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<io::Result<()>> {
        std::pin::Pin::new(&mut self.pipe).poll_read(cx, buf)
    }
}

impl AsyncWrite for NoiseStream {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<io::Result<usize>> {
        std::pin::Pin::new(&mut self.pipe).poll_write(cx, buf)
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<io::Result<()>> {
        std::pin::Pin::new(&mut self.pipe).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<io::Result<()>> {
        std::pin::Pin::new(&mut self.pipe).poll_shutdown(cx)
    }
}

/// The client's side of a handshake over `stream`, within `timeout`.
pub async fn initiate<S>(mut stream: S, key: &Key, timeout: Duration) -> io::Result<NoiseStream>
where
    S: AsyncRead + AsyncWrite + Send + Unpin + 'static,
{
    let handshake = async {
        let mut state = key
            .builder()
            .and_then(|b| b.build_initiator())
            .map_err(|e| noise_error("starting the handshake", e))?;
        let mut buf = vec![0u8; MAX_HANDSHAKE];
        let n = state
            .write_message(&[], &mut buf)
            .map_err(|e| noise_error("writing the handshake", e))?;
        write_message(&mut stream, buf.get(..n).unwrap_or_default()).await?;
        let n = match read_message(&mut stream, &mut buf, MAX_HANDSHAKE).await {
            Ok(n) => n,
            Err(e) if is_closed(&e) => {
                return Err(io::Error::new(
                    io::ErrorKind::ConnectionRefused,
                    "the server closed the connection during the handshake: the key may be \
                     wrong (both ends need the same key file), or the server is at its \
                     connection limit",
                ))
            }
            Err(e) => {
                return Err(noise_error(
                    "the server's handshake does not parse (does it use a key?)",
                    e,
                ))
            }
        };
        let mut none = [0u8; 0];
        state
            .read_message(buf.get(..n).unwrap_or_default(), &mut none)
            .map_err(|e| noise_error("the server's handshake does not verify (another key?)", e))?;
        let mut transport = state
            .into_transport_mode()
            .map_err(|e| noise_error("finishing the handshake", e))?;
        // The proof that this is a live session, not a replay.
        let n = transport
            .write_message(&[], &mut buf)
            .map_err(|e| noise_error("confirming the handshake", e))?;
        write_message(&mut stream, buf.get(..n).unwrap_or_default()).await?;
        Ok(transport)
    };
    let transport = tokio::time::timeout(timeout, handshake)
        .await
        .map_err(|_| {
            io::Error::new(
                io::ErrorKind::TimedOut,
                format!(
                    "no handshake within {timeout:?}: the server may not use a key (drop --key), \
                     or it is overloaded"
                ),
            )
        })??;
    Ok(spawn(stream, transport, Vec::new()))
}

/// The listener's side of a handshake over `stream`, within `timeout`.
/// Nothing is written until the client's first message verifies with the
/// key; the stream is returned only once the client has proved it holds
/// this session's keys.
pub async fn accept<S>(mut stream: S, key: &Key, timeout: Duration) -> io::Result<NoiseStream>
where
    S: AsyncRead + AsyncWrite + Send + Unpin + 'static,
{
    let handshake = async {
        let mut state = key
            .builder()
            .and_then(|b| b.build_responder())
            .map_err(|e| noise_error("starting the handshake", e))?;
        let mut buf = vec![0u8; MAX_MESSAGE];
        let n = read_message(&mut stream, &mut buf, MAX_HANDSHAKE).await?;
        let mut none = [0u8; 0];
        state
            .read_message(buf.get(..n).unwrap_or_default(), &mut none)
            .map_err(|e| {
                noise_error(
                    "the first handshake message does not verify (wrong key?)",
                    e,
                )
            })?;
        let mut reply = [0u8; MAX_HANDSHAKE];
        let n = state
            .write_message(&[], &mut reply)
            .map_err(|e| noise_error("writing the handshake", e))?;
        write_message(&mut stream, reply.get(..n).unwrap_or_default()).await?;
        let mut transport = state
            .into_transport_mode()
            .map_err(|e| noise_error("finishing the handshake", e))?;
        let n = read_message(&mut stream, &mut buf, MAX_MESSAGE).await?;
        let mut plain = vec![0u8; n];
        let m = transport
            .read_message(buf.get(..n).unwrap_or_default(), &mut plain)
            .map_err(|e| {
                noise_error(
                    "the handshake's confirmation does not verify (a replay?)",
                    e,
                )
            })?;
        plain.truncate(m);
        Ok::<_, io::Error>((transport, plain))
    };
    let (transport, first) = tokio::time::timeout(timeout, handshake)
        .await
        .map_err(|_| {
            io::Error::new(
                io::ErrorKind::TimedOut,
                format!("no complete handshake within {timeout:?}"),
            )
        })??;
    Ok(spawn(stream, transport, first))
}

/// Whether `e` means the peer closed or reset the connection.
fn is_closed(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::UnexpectedEof
            | io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::BrokenPipe
    )
}

/// Starts the task that encrypts and decrypts between `stream` and the
/// returned stream's pipe; `first` is plaintext already received.
fn spawn<S>(stream: S, transport: snow::TransportState, first: Vec<u8>) -> NoiseStream
where
    S: AsyncRead + AsyncWrite + Send + Unpin + 'static,
{
    let (pipe, inner) = tokio::io::duplex(PIPE);
    let task = tokio::spawn(async move {
        let transport = Arc::new(Mutex::new(transport));
        let (mut net_rx, mut net_tx) = tokio::io::split(stream);
        let (mut plain_rx, mut plain_tx) = tokio::io::split(inner);
        let inbound = {
            let transport = transport.clone();
            async move {
                plain_tx.write_all(&first).await?;
                let mut msg = vec![0u8; MAX_MESSAGE];
                let mut plain = vec![0u8; MAX_MESSAGE];
                loop {
                    let n = read_message(&mut net_rx, &mut msg, MAX_MESSAGE).await?;
                    let m = lock(&transport)
                        .read_message(msg.get(..n).unwrap_or_default(), &mut plain)
                        .map_err(|e| noise_error("a message does not verify", e))?;
                    plain_tx
                        .write_all(plain.get(..m).unwrap_or_default())
                        .await?;
                }
            }
        };
        let outbound = async move {
            let mut plain = vec![0u8; MAX_MESSAGE - TAG];
            let mut msg = vec![0u8; MAX_MESSAGE];
            loop {
                let n = plain_rx.read(&mut plain).await?;
                if n == 0 {
                    net_tx.shutdown().await?;
                    return Ok::<(), io::Error>(());
                }
                let m = lock(&transport)
                    .write_message(plain.get(..n).unwrap_or_default(), &mut msg)
                    .map_err(|e| noise_error("encrypting", e))?;
                write_message(&mut net_tx, msg.get(..m).unwrap_or_default()).await?;
            }
        };
        let result: io::Result<()> = tokio::select! {
            r = inbound => r,
            r = outbound => r,
        };
        if let Err(e) = result {
            tracing::debug!("keyed link ended: {e}");
        }
    });
    NoiseStream { pipe, task }
}

fn lock(t: &Mutex<snow::TransportState>) -> std::sync::MutexGuard<'_, snow::TransportState> {
    // Every use is one whole encrypt or decrypt: a panic cannot leave it
    // half-done.
    t.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn key_files_round_trip_and_reject_garbage() {
        let key = Key::generate().unwrap();
        assert_eq!(Key::parse(&key.to_file_text()).unwrap(), key);
        assert!(Key::parse("").is_err());
        assert!(Key::parse("abcd").is_err());
        assert!(Key::parse(&"zz".repeat(32)).is_err());
        assert!(Key::parse(&format!("{}\n{}", "00".repeat(32), "11".repeat(32))).is_err());
        assert!(Key::parse(&"é".repeat(32)).is_err());
        assert_eq!(format!("{key:?}"), "Key(..)");
    }

    #[test]
    fn key_errors_are_named_and_display() {
        assert!(matches!(Key::parse(""), Err(KeyError::LineCount)));
        assert!(matches!(Key::parse("abcd"), Err(KeyError::Length(4))));
        let err = Key::parse(&"zz".repeat(32)).unwrap_err();
        assert!(matches!(err, KeyError::NotHex { position: 0, .. }));
        assert_eq!(
            err.to_string(),
            "\"zz\" at position 0 is not a hex digit pair"
        );
        assert_eq!(
            KeyError::LineCount.to_string(),
            "a key file holds exactly one line of 64 hex digits"
        );
        assert_eq!(
            KeyError::Length(4).to_string(),
            "the key is 4 characters long, not 64 hex digits"
        );
    }
}
