//! The wire format: key expressions for tuples, remote sets and presence, and the attachment that carries metadata.
//!
//! Pure functions with no zenoh types, so the format is tested (and documented in `docs/tuples.md`) on its own.
//!
//! Attachment layout, integers little-endian (`docs/tuples.md`, "Compatibility", is the policy):
//!
//! | bytes | field |
//! | --- | --- |
//! | 1 | version: `1`, or `2` when it carries a creator |
//! | 1 | flags: bit 0 `ts_user` present, bit 1 `expiry` present, bit 2 removal by expiry (on deletes), bit 3 `epoch` present, bit 4 `creator` present (version 2); other bits ignored |
//! | 8 | `seq` (u64) |
//! | 8 | `ts_write`, nanoseconds since the UNIX epoch (u64) |
//! | 8 | `ts_user` (u64), only if flag bit 0 |
//! | 8 | `expiry` (u64, ns since epoch), only if flag bit 1; in a remote-set request: time to live in ns |
//! | 8 | `epoch` (u64): the owner's run, only if flag bit 3; absent means 0 |
//! | 1 | mimetype length `n` |
//! | n | mimetype, printable ASCII |
//! | 1 | creator length `m`, only if flag bit 4 (version 2) |
//! | m | creator: the PEIS whose remote set wrote the value (in a remote-set request: the requester), only if flag bit 4 |
//!
//! Version 1 is the earlier format: nothing follows the mimetype (a creator under bit 4 is read,
//! as executives wrote it for a while under version 1). From version 2 on, a reader ignores what
//! follows the fields it knows, and reads a version above the ones it knows by the fields of the
//! highest it knows: a later version may only append.

use std::time::Duration;

use bytes::Bytes;
use ecology_tuples::{
    Key, KeyPattern, Mimetype, OwnerPattern, PeisId, Segment, Timestamp, Tuple, TuplePattern, Value,
};

/// First chunk of every key expression of the tuple space.
pub const ROOT: &str = "peis";
/// The attachment's earlier version: no creator, and nothing after the mimetype.
pub const VERSION_1: u8 = 1;
/// The highest version of the attachment this implementation reads and writes: version 1 and
/// the creator (flag bit 4). A writer writes it only when there is a creator to carry.
pub const VERSION: u8 = 2;

/// The tuple in which every PEIS announces the highest attachment version it reads, as decimal
/// text (`2`). A PEIS that has not announced one reads version 1.
pub const CONTRACT_KEY: &str = "contract";

/// The contract version a PEIS announces in its tuple [`CONTRACT_KEY`], read from its text: a
/// positive decimal number (capped at 255). `None` for anything else.
pub fn parse_contract(text: &str) -> Option<u8> {
    let text = text.trim();
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let version = text
        .trim_start_matches('0')
        .parse::<u64>()
        .map_or(u8::MAX, |v| u8::try_from(v).unwrap_or(u8::MAX));
    (version > 0).then_some(version)
}

const FLAG_TS_USER: u8 = 1;
const FLAG_EXPIRY: u8 = 1 << 1;
const FLAG_EXPIRED: u8 = 1 << 2;
const FLAG_EPOCH: u8 = 1 << 3;
const FLAG_CREATOR: u8 = 1 << 4;

/// Why bytes from the network could not be read as a tuple.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// The key expression is not `peis/OWNER/KEY…` with a valid owner and key.
    #[error("key expression {0:?} is not peis/OWNER/KEY")]
    KeyExpr(String),
    /// The attachment is not a valid metadata record.
    #[error("malformed attachment: {0}")]
    Attachment(&'static str),
    /// A bundle of held tuples is not valid.
    #[error("malformed bundle: {0}")]
    Bundle(&'static str),
    /// The value is over the receiver's size limit.
    #[error("value of {size} bytes is over the limit of {limit} bytes")]
    TooLarge {
        /// Size of the value.
        size: usize,
        /// The receiver's limit.
        limit: usize,
    },
}

/// `peis/OWNER/k/e/y` for tuple (OWNER, k.e.y).
pub fn tuple_key_expr(owner: &PeisId, key: &Key) -> String {
    let mut ke = String::with_capacity(ROOT.len() + owner.as_str().len() + key.as_str().len() + 2);
    ke.push_str(ROOT);
    ke.push('/');
    ke.push_str(owner.as_str());
    ke.push('/');
    for (i, segment) in key.segments().enumerate() {
        if i > 0 {
            ke.push('/');
        }
        ke.push_str(segment);
    }
    ke
}

/// `peis/OWNER/@set/k/e/y`: where a remote set of (OWNER, k.e.y) is sent as a query in the open
/// mode; who asked is the request's creator stamp, which nothing checks.
pub fn remote_set_key_expr(owner: &PeisId, key: &Key) -> String {
    format!("{ROOT}/{owner}/@set/{}", key.as_str().replace('.', "/"))
}

/// `peis/OWNER/@by/REQUESTER/k/e/y`: a remote set of (OWNER, k.e.y) that names who asks, the form
/// of the secured mode. The access rules let a member query only under its own name there, so
/// the owner knows the requester from the key expression.
pub fn requested_set_key_expr(owner: &PeisId, requester: &PeisId, key: &Key) -> String {
    format!(
        "{ROOT}/{owner}/@by/{requester}/{}",
        key.as_str().replace('.', "/")
    )
}

/// `peis/OWNER/@alive`: the liveliness token of a present PEIS.
pub fn alive_key_expr(owner: &PeisId) -> String {
    format!("{ROOT}/{owner}/@alive")
}

/// `peis/*/@alive`: every PEIS's liveliness token.
pub const ALL_ALIVE: &str = "peis/*/@alive";

/// The key expression covering a tuple pattern: `*` and `**` map to Zenoh's `*` and `**`.
pub fn pattern_key_expr(pattern: &TuplePattern) -> String {
    let owner = match &pattern.owner {
        OwnerPattern::Exact(id) => id.as_str().to_owned(),
        OwnerPattern::Any => "*".to_owned(),
    };
    let key = key_pattern_chunks(&pattern.key);
    format!("{ROOT}/{owner}/{key}")
}

fn key_pattern_chunks(pattern: &KeyPattern) -> String {
    // Zenoh's canonical form puts `*` before `**` when they are adjacent; both orders match the same keys.
    let mut chunks: Vec<&str> = pattern
        .segments()
        .iter()
        .map(|s| match s {
            Segment::Exact(s) => s,
            Segment::One => "*",
            Segment::Any => "**",
        })
        .collect();
    let mut i = 0;
    while i + 1 < chunks.len() {
        if chunks[i] == "**" && chunks[i + 1] == "*" {
            chunks.swap(i, i + 1);
            i = i.saturating_sub(1);
        } else {
            i += 1;
        }
    }
    chunks.join("/")
}

/// Reads (owner, key) from `peis/OWNER/k/e/y`.
pub fn parse_tuple_key_expr(ke: &str) -> Result<(PeisId, Key), WireError> {
    parse_tuple_key_expr_reusing(ke, None)
}

/// Reads (owner, key) like [`parse_tuple_key_expr`], taking `known` instead of a new name when
/// the key expression names that owner (a bundle holds each PEIS's tuples one after another).
pub fn parse_tuple_key_expr_reusing(
    ke: &str,
    known: Option<&PeisId>,
) -> Result<(PeisId, Key), WireError> {
    let fail = || WireError::KeyExpr(ke.to_owned());
    let rest = ke
        .strip_prefix(ROOT)
        .and_then(|r| r.strip_prefix('/'))
        .ok_or_else(fail)?;
    let (owner, key) = rest.split_once('/').ok_or_else(fail)?;
    let owner = match known {
        Some(known) if known.as_str() == owner => known.clone(),
        _ => PeisId::new(owner).map_err(|_| fail())?,
    };
    let key = key_of_chunks(key).ok_or_else(fail)?;
    Ok((owner, key))
}

/// The key whose segments are `chunks` (`a/b/c` → `a.b.c`), in its one canonical spelling: each
/// chunk a single segment. `a/b.c` would name the same key as `a/b/c`, but slip past an access
/// rule that matches chunks (`a/*` takes the chunk `b.c`), so it names nothing.
fn key_of_chunks(chunks: &str) -> Option<Key> {
    if chunks.contains('.') {
        return None;
    }
    Key::new(&chunks.replace('/', ".")).ok()
}

/// Reads a remote set's key expression, given OWNER: the requester it names (`peis/OWNER/@by/REQUESTER/k/e/y`)
/// or `None` (`peis/OWNER/@set/k/e/y`), and the key.
pub fn parse_remote_set_key_expr(
    owner: &PeisId,
    ke: &str,
) -> Result<(Option<PeisId>, Key), WireError> {
    let fail = || WireError::KeyExpr(ke.to_owned());
    let rest = ke
        .strip_prefix(ROOT)
        .and_then(|r| r.strip_prefix('/'))
        .and_then(|r| r.strip_prefix(owner.as_str()))
        .and_then(|r| r.strip_prefix('/'))
        .ok_or_else(fail)?;
    let (requester, key) = if let Some(key) = rest.strip_prefix("@set/") {
        (None, key)
    } else {
        let (requester, key) = rest
            .strip_prefix("@by/")
            .and_then(|r| r.split_once('/'))
            .ok_or_else(fail)?;
        (Some(PeisId::new(requester).map_err(|_| fail())?), key)
    };
    let key = key_of_chunks(key).ok_or_else(fail)?;
    Ok((requester, key))
}

/// Reads OWNER from `peis/OWNER/@alive`.
pub fn parse_alive_key_expr(ke: &str) -> Result<PeisId, WireError> {
    ke.strip_prefix(ROOT)
        .and_then(|r| r.strip_prefix('/'))
        .and_then(|r| r.strip_suffix("/@alive"))
        .and_then(|owner| PeisId::new(owner).ok())
        .ok_or_else(|| WireError::KeyExpr(ke.to_owned()))
}

/// Tuple metadata as carried in an attachment.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Metadata {
    /// Per-key version.
    pub seq: u64,
    /// Write time on the owner's clock.
    pub ts_write: Timestamp,
    /// Writer's own timestamp.
    pub ts_user: Option<Timestamp>,
    /// Expiry time (or, in a remote-set request, time to live in ns).
    pub expiry: Option<u64>,
    /// Whether a delete sample reports an expiry rather than a delete.
    pub expired: bool,
    /// The owner's run (0: unknown).
    pub epoch: u64,
    /// Mimetype of the data.
    pub mimetype: Mimetype,
    /// The PEIS whose remote set wrote the value; in a remote-set request, the requester.
    pub creator: Option<PeisId>,
}

impl Metadata {
    /// The metadata of `tuple`.
    pub fn of_tuple(tuple: &Tuple) -> Self {
        Self {
            seq: tuple.seq,
            ts_write: tuple.ts_write,
            ts_user: tuple.ts_user,
            expiry: tuple.expiry.map(Timestamp::as_nanos),
            expired: false,
            epoch: tuple.epoch,
            mimetype: tuple.mimetype.clone(),
            creator: tuple.creator.clone(),
        }
    }

    /// The metadata of a remote-set request for `value`.
    pub fn of_request(value: &Value) -> Self {
        Self {
            seq: 0,
            ts_write: Timestamp(0),
            ts_user: value.ts_user,
            expiry: value
                .time_to_live
                .map(|ttl| u64::try_from(ttl.as_nanos()).unwrap_or(u64::MAX)),
            expired: false,
            epoch: 0,
            mimetype: value.mimetype.clone(),
            creator: value.creator.clone(),
        }
    }

    /// Metadata for a delete sample.
    pub fn of_removal(seq: u64, epoch: u64, ts_write: Timestamp, expired: bool) -> Self {
        Self {
            seq,
            ts_write,
            ts_user: None,
            expiry: None,
            expired,
            epoch,
            mimetype: Mimetype::octet_stream(),
            creator: None,
        }
    }

    /// Serializes the metadata in the layout of the module documentation: version 1 when there
    /// is no creator (byte for byte the earlier format), version 2 when there is.
    pub fn encode(&self) -> Vec<u8> {
        let mime = self.mimetype.as_str().as_bytes();
        let mut out = Vec::with_capacity(2 + 8 * 5 + 1 + mime.len());
        let mut flags = 0;
        if self.ts_user.is_some() {
            flags |= FLAG_TS_USER;
        }
        if self.expiry.is_some() {
            flags |= FLAG_EXPIRY;
        }
        if self.expired {
            flags |= FLAG_EXPIRED;
        }
        if self.epoch != 0 {
            flags |= FLAG_EPOCH;
        }
        if self.creator.is_some() {
            flags |= FLAG_CREATOR;
        }
        out.push(if self.creator.is_some() {
            VERSION
        } else {
            VERSION_1
        });
        out.push(flags);
        out.extend_from_slice(&self.seq.to_le_bytes());
        out.extend_from_slice(&self.ts_write.as_nanos().to_le_bytes());
        if let Some(ts) = self.ts_user {
            out.extend_from_slice(&ts.as_nanos().to_le_bytes());
        }
        if let Some(expiry) = self.expiry {
            out.extend_from_slice(&expiry.to_le_bytes());
        }
        if self.epoch != 0 {
            out.extend_from_slice(&self.epoch.to_le_bytes());
        }
        // Mimetypes are at most 255 bytes (checked by `Mimetype::new`).
        out.push(u8::try_from(mime.len()).unwrap_or(u8::MAX));
        out.extend_from_slice(mime);
        if let Some(creator) = &self.creator {
            // PEIS names are at most 255 bytes (checked by `PeisId::new`).
            let name = creator.as_str().as_bytes();
            out.push(u8::try_from(name.len()).unwrap_or(u8::MAX));
            out.extend_from_slice(name);
        }
        out
    }

    /// Parses an attachment of any version: unknown flag bits are ignored, and so is anything after
    /// the known fields from version 2 on. Truncated fields, a bad mimetype or creator, version 0,
    /// and bytes after the fields of version 1 are errors.
    pub fn decode(bytes: &[u8]) -> Result<Self, WireError> {
        Self::decode_reusing(bytes, None)
    }

    /// Parses an attachment like [`Metadata::decode`], taking `known` instead of a new mimetype when the
    /// attachment names the same one (a subscriber sees the same few mimetypes over and over).
    pub fn decode_reusing(bytes: &[u8], known: Option<&Mimetype>) -> Result<Self, WireError> {
        let mut r = Reader(bytes);
        let version = r.u8()?;
        if version == 0 {
            return Err(WireError::Attachment("unknown version"));
        }
        let flags = r.u8()?;
        let seq = r.u64()?;
        let ts_write = Timestamp(r.u64()?);
        let ts_user = if flags & FLAG_TS_USER != 0 {
            Some(Timestamp(r.u64()?))
        } else {
            None
        };
        let expiry = if flags & FLAG_EXPIRY != 0 {
            Some(r.u64()?)
        } else {
            None
        };
        let epoch = if flags & FLAG_EPOCH != 0 { r.u64()? } else { 0 };
        let len = usize::from(r.u8()?);
        let mime = r.take(len)?;
        // Version 1 knew no creator; executives wrote one under it for a while, after the mimetype.
        let has_creator = flags & FLAG_CREATOR != 0 && (version > VERSION_1 || !r.0.is_empty());
        let creator = if has_creator {
            let len = usize::from(r.u8()?);
            let name = std::str::from_utf8(r.take(len)?)
                .map_err(|_| WireError::Attachment("creator is not UTF-8"))?;
            Some(PeisId::new(name).map_err(|_| WireError::Attachment("invalid creator"))?)
        } else {
            None
        };
        // Version 1 said nothing may follow; later versions may append fields we do not know.
        if version == VERSION_1 && !r.0.is_empty() {
            return Err(WireError::Attachment("trailing bytes"));
        }
        let mimetype = match known {
            Some(known) if known.as_str().as_bytes() == mime => known.clone(),
            _ => {
                let mime = std::str::from_utf8(mime)
                    .map_err(|_| WireError::Attachment("mimetype is not UTF-8"))?;
                Mimetype::new(mime).map_err(|_| WireError::Attachment("invalid mimetype"))?
            }
        };
        Ok(Self {
            seq,
            ts_write,
            ts_user,
            expiry,
            expired: flags & FLAG_EXPIRED != 0,
            epoch,
            mimetype,
            creator,
        })
    }

    /// The tuple (owner, key) with `data` and this metadata.
    pub fn into_tuple(self, owner: PeisId, key: Key, data: Bytes) -> Tuple {
        Tuple {
            owner,
            key,
            data,
            mimetype: self.mimetype,
            ts_write: self.ts_write,
            ts_user: self.ts_user,
            expiry: self.expiry.map(Timestamp),
            seq: self.seq,
            epoch: self.epoch,
            creator: self.creator,
        }
    }

    /// The value a remote-set request with `data` and this metadata asks for.
    pub fn into_request(self, data: Bytes) -> Value {
        Value {
            data,
            mimetype: self.mimetype,
            ts_user: self.ts_user,
            time_to_live: self.expiry.map(Duration::from_nanos),
            creator: self.creator,
        }
    }
}

/// The selector parameter with which a querier asks a router that holds the contract for its
/// answer as one [bundle](encode_bundle) instead of one reply per tuple. A router that does not
/// know it ignores it and replies per tuple; a PEIS answering for itself ignores it too.
pub const BUNDLE_PARAMETER: &str = "ecology_bundle";

/// The Zenoh encoding of a reply that is a bundle; any other reply is one tuple.
pub const BUNDLE_ENCODING: &str = "application/x-ecology-bundle";

/// The only layout of a bundle so far, its first byte.
const BUNDLE_VERSION: u8 = 1;

/// One tuple in a bundle, as its owner last sent it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bundled<'a> {
    /// Its key expression, `peis/OWNER/…`.
    pub key_expr: &'a str,
    /// Its Zenoh encoding, as text (what a sample without an attachment is read by).
    pub encoding: &'a str,
    /// Its value.
    pub payload: &'a [u8],
    /// Its attachment, if it had one.
    pub attachment: Option<&'a [u8]>,
}

/// Many tuples in one reply, integers little-endian: a version byte (`1`), the number of tuples
/// (u32), each tuple as its key expression (u16 length, UTF-8), encoding (u8 length, UTF-8),
/// payload (u32 length) and attachment (u32 length, `0xFFFFFFFF` for none); then, to the end,
/// the names of the PEIS present that the sender holds nothing for under the question (u8
/// length, UTF-8 each), which a querier asks itself. Parts too long for their length field are
/// cut off at the field's limit, which no valid tuple or name reaches.
pub fn encode_bundle<'a>(
    tuples: impl IntoIterator<Item = Bundled<'a>>,
    silent: impl IntoIterator<Item = &'a str>,
) -> Vec<u8> {
    let mut bundle = BundleWriter::default();
    for t in tuples {
        bundle.push(t);
    }
    for name in silent {
        bundle.silent(name);
    }
    bundle.finish()
}

/// A bundle written one tuple, and one silent PEIS, at a time (see [`encode_bundle`]).
#[derive(Debug)]
pub struct BundleWriter {
    out: Vec<u8>,
    tuples: u32,
    silent: Vec<u8>,
}

impl Default for BundleWriter {
    fn default() -> Self {
        let mut out = vec![BUNDLE_VERSION];
        out.extend_from_slice(&0u32.to_le_bytes());
        BundleWriter {
            out,
            tuples: 0,
            silent: Vec::new(),
        }
    }
}

/// Appends `bytes` after their length in `width` bytes, cut off at what that length can say.
fn length_and(out: &mut Vec<u8>, bytes: &[u8], width: usize) {
    let limit = (1u64 << (8 * width)) - 1;
    let len = bytes
        .len()
        .min(usize::try_from(limit - 1).unwrap_or(usize::MAX));
    out.extend_from_slice(&(len as u64).to_le_bytes()[..width]);
    out.extend_from_slice(&bytes[..len]);
}

impl BundleWriter {
    /// Appends one tuple.
    pub fn push(&mut self, t: Bundled<'_>) {
        let out = &mut self.out;
        length_and(out, t.key_expr.as_bytes(), 2);
        length_and(out, t.encoding.as_bytes(), 1);
        length_and(out, t.payload, 4);
        match t.attachment {
            Some(attachment) => length_and(out, attachment, 4),
            None => out.extend_from_slice(&u32::MAX.to_le_bytes()),
        }
        self.tuples = self.tuples.saturating_add(1);
    }

    /// Names a PEIS present that nothing is held for under the question.
    pub fn silent(&mut self, peis: &str) {
        length_and(&mut self.silent, peis.as_bytes(), 1);
    }

    /// The bundle's bytes.
    pub fn finish(mut self) -> Vec<u8> {
        self.out[1..5].copy_from_slice(&self.tuples.to_le_bytes());
        self.out.extend_from_slice(&self.silent);
        self.out
    }
}

/// A bundle as read: its tuples, and the PEIS present it holds nothing for.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Bundle<'a> {
    /// Its tuples, in order.
    pub tuples: Vec<Bundled<'a>>,
    /// The names of the PEIS present that its sender held nothing for under the question.
    pub silent: Vec<&'a str>,
}

/// Reads a bundle made by [`encode_bundle`], or an error for a version it does not know, a
/// truncated part, or text that is not UTF-8.
pub fn decode_bundle(bytes: &[u8]) -> Result<Bundle<'_>, WireError> {
    fn text(b: &[u8]) -> Result<&str, WireError> {
        std::str::from_utf8(b).map_err(|_| WireError::Bundle("text that is not UTF-8"))
    }
    let bad = |e: WireError| match e {
        WireError::Attachment(why) => WireError::Bundle(why),
        other => other,
    };
    let mut r = Reader(bytes);
    if r.u8().map_err(bad)? != BUNDLE_VERSION {
        return Err(WireError::Bundle("unknown version"));
    }
    let count = r.peek_u32().ok_or(WireError::Bundle("too short"))?;
    r.take(4).map_err(bad)?;
    let mut bundle = Bundle::default();
    for _ in 0..count {
        let key_expr = text(r.part(2).map_err(bad)?)?;
        let encoding = text(r.part(1).map_err(bad)?)?;
        let payload = r.part(4).map_err(bad)?;
        let attachment = match r.peek_u32() {
            Some(u32::MAX) => {
                r.take(4).map_err(bad)?;
                None
            }
            _ => Some(r.part(4).map_err(bad)?),
        };
        bundle.tuples.push(Bundled {
            key_expr,
            encoding,
            payload,
            attachment,
        });
    }
    while !r.0.is_empty() {
        bundle.silent.push(text(r.part(1).map_err(bad)?)?);
    }
    Ok(bundle)
}

struct Reader<'a>(&'a [u8]);

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], WireError> {
        if self.0.len() < n {
            return Err(WireError::Attachment("too short"));
        }
        let (head, tail) = self.0.split_at(n);
        self.0 = tail;
        Ok(head)
    }

    fn u8(&mut self) -> Result<u8, WireError> {
        Ok(self.take(1)?[0])
    }

    fn u64(&mut self) -> Result<u64, WireError> {
        let mut buf = [0; 8];
        buf.copy_from_slice(self.take(8)?);
        Ok(u64::from_le_bytes(buf))
    }

    /// A length of `width` bytes, then that many bytes.
    fn part(&mut self, width: usize) -> Result<&'a [u8], WireError> {
        let mut buf = [0; 8];
        buf[..width].copy_from_slice(self.take(width)?);
        let len = usize::try_from(u64::from_le_bytes(buf))
            .map_err(|_| WireError::Attachment("too short"))?;
        self.take(len)
    }

    fn peek_u32(&self) -> Option<u32> {
        let head: [u8; 4] = self.0.get(..4)?.try_into().ok()?;
        Some(u32::from_le_bytes(head))
    }
}
