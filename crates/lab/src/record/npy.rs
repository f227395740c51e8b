//! NumPy arrays on disk: `.npy` files and `.npz` archives, read to a shape and `f64` values.
//!
//! ## `.npy` (format versions 1.0, 2.0, 3.0)
//! ```text
//! \x93NUMPY  major minor  header_len (u16 LE in v1, u32 LE in v2/v3)  header  data
//! header: {'descr': '<f8', 'fortran_order': False, 'shape': (8192, 3, 6, 2), }
//! ```
//! The header is a Python dict literal (ASCII in v1/v2, UTF-8 in v3). Accepted element types:
//! `'<f8'`, `'<f4'` and their big-endian forms `'>f8'`, `'>f4'`; `f4` values are widened to
//! `f64` exactly. Any number of dimensions (a 0-d array is one value). A Fortran-ordered
//! array is returned in C order, so [`NpyArray::data`] is always row-major: the last index
//! varies fastest. The data must be exactly `Π shape · itemsize` bytes (nothing is allocated
//! before that is checked, so a header cannot make the reader allocate more than the file
//! holds).
//!
//! ## `.npz`
//! A zip archive of `.npy` members (as `numpy.savez` / `savez_compressed` write it):
//! members stored or deflated, with ZIP64 sizes and offsets. The container is read here
//! (end of central directory, central directory, local headers, CRC-32); deflate is
//! `miniz_oxide`'s. A member may inflate to at most [`MAX_MEMBER_BYTES`].
//!
//! Every failure is an [`NpyError`] that names the file and what is wrong; no input makes
//! the reader panic (a property test feeds it arbitrary and mutated bytes).

use std::fmt;
use std::path::Path;

/// Largest member of an `.npz` archive, inflated (bytes): 2 GiB.
pub const MAX_MEMBER_BYTES: usize = 1 << 31;
/// Largest `.npy` header (bytes); NumPy writes a few hundred.
pub const MAX_HEADER_BYTES: usize = 1 << 20;
/// Most dimensions of an array (NumPy's own limit).
pub const MAX_DIMS: usize = 64;

/// An array read from a `.npy` file or `.npz` member: its shape and its values in C order.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    /// Length of each dimension (empty for a 0-d array).
    pub shape: Vec<usize>,
    /// Values, row-major (the last index fastest), as `f64`.
    pub data: Vec<f64>,
}

impl NpyArray {
    /// The flat index of a multi-index (row-major), `None` if the rank or an index is out of
    /// range.
    pub fn index(&self, idx: &[usize]) -> Option<usize> {
        if idx.len() != self.shape.len() {
            return None;
        }
        let mut flat = 0usize;
        for (&i, &n) in idx.iter().zip(&self.shape) {
            if i >= n {
                return None;
            }
            flat = flat * n + i;
        }
        Some(flat)
    }

    /// The value at a multi-index, `None` out of range.
    pub fn get(&self, idx: &[usize]) -> Option<f64> {
        self.index(idx).and_then(|i| self.data.get(i).copied())
    }
}

/// What is wrong with a `.npy` file or `.npz` archive; part of an [`NpyError`].
#[derive(Debug)]
#[non_exhaustive]
pub enum NpyErrorKind {
    /// The file could not be read.
    Io(std::io::Error),
    /// The file does not start with `\x93NUMPY`.
    NotNpy,
    /// A format version other than 1.0, 2.0, 3.0.
    Version(u8, u8),
    /// The file ends before the named part.
    Truncated(&'static str),
    /// The header cannot be read: what is wrong.
    Header(String),
    /// An element type other than `<f8`, `<f4`, `>f8`, `>f4`.
    Dtype(String),
    /// The data are not as many bytes as the shape needs.
    DataLength {
        /// Bytes the shape and element type need.
        expected: u128,
        /// Bytes after the header.
        found: usize,
    },
    /// The archive is not a zip file NumPy writes: what is wrong.
    Zip(String),
    /// A member of the archive is compressed by a method other than stored (0) or deflate (8).
    Method(u16),
    /// A member's CRC-32 does not match its contents.
    Crc {
        /// The member.
        member: String,
    },
    /// A member larger than [`MAX_MEMBER_BYTES`] inflated.
    TooLarge {
        /// The member.
        member: String,
    },
    /// A named member is not in the archive.
    NoMember {
        /// The name asked for.
        name: String,
        /// The members found.
        found: String,
    },
    /// An error of an archive's member, with its name.
    InMember {
        /// The member.
        member: String,
        /// What is wrong with it.
        kind: Box<NpyErrorKind>,
    },
}

impl fmt::Display for NpyErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io(e) => write!(f, "{e}"),
            Self::NotNpy => write!(f, "not a NumPy .npy file (no \\x93NUMPY magic)"),
            Self::Version(a, b) => write!(f, "unknown .npy format version {a}.{b} (1.0, 2.0, 3.0 are read)"),
            Self::Truncated(what) => write!(f, "the file ends inside the {what}"),
            Self::Header(what) => write!(f, "bad .npy header: {what}"),
            Self::Dtype(d) => write!(f, "element type {d:?} is not read ('<f8', '<f4', '>f8', '>f4' are)"),
            Self::DataLength { expected, found } => {
                write!(f, "the shape needs {expected} bytes of data, the file has {found}")
            }
            Self::Zip(what) => write!(f, "bad .npz (zip) archive: {what}"),
            Self::Method(m) => write!(f, "zip compression method {m} is not read (stored and deflate are)"),
            Self::Crc { member } => write!(f, "member {member:?}: CRC-32 mismatch (corrupt archive)"),
            Self::TooLarge { member } => {
                write!(f, "member {member:?} inflates to more than {MAX_MEMBER_BYTES} bytes")
            }
            Self::NoMember { name, found } => write!(f, "no member {name:?} (found: {found})"),
            Self::InMember { member, kind } => write!(f, "member {member:?}: {kind}"),
        }
    }
}

/// A `.npy` file or `.npz` archive that cannot be read. `Display`: `FILE: what is wrong`.
#[derive(Debug)]
pub struct NpyError {
    /// The file, or the name the caller gave the bytes.
    pub source: String,
    /// What is wrong.
    pub kind: NpyErrorKind,
}

impl fmt::Display for NpyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.source, self.kind)
    }
}

impl std::error::Error for NpyError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.kind {
            NpyErrorKind::Io(e) => Some(e),
            _ => None,
        }
    }
}

fn err(source: &str, kind: NpyErrorKind) -> NpyError {
    NpyError { source: source.to_string(), kind }
}

/// Reads a `.npy` file.
pub fn read_npy(path: impl AsRef<Path>) -> Result<NpyArray, NpyError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| err(&name, NpyErrorKind::Io(e)))?;
    parse_npy(&bytes).map_err(|kind| err(&name, kind))
}

/// Reads every member of a `.npz` archive, in archive order, named without the `.npy`
/// suffix (as `numpy.load(...)[name]` names them).
pub fn read_npz(path: impl AsRef<Path>) -> Result<Vec<(String, NpyArray)>, NpyError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| err(&name, NpyErrorKind::Io(e)))?;
    parse_npz(&bytes).map_err(|kind| err(&name, kind))
}

/// Parses the bytes of a `.npy` file.
///
/// ```
/// use boucwen_lab::record::npy::parse_npy;
/// let mut file = b"\x93NUMPY\x01\x00".to_vec();
/// let header = "{'descr': '<f8', 'fortran_order': False, 'shape': (2,), }";
/// file.extend_from_slice(&(header.len() as u16).to_le_bytes());
/// file.extend_from_slice(header.as_bytes());
/// for v in [1.5f64, -2.0] { file.extend_from_slice(&v.to_le_bytes()); }
/// let a = parse_npy(&file).unwrap();
/// assert_eq!((a.shape, a.data), (vec![2], vec![1.5, -2.0]));
/// ```
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray, NpyErrorKind> {
    if bytes.len() < 8 || &bytes[..6] != b"\x93NUMPY" {
        return Err(if bytes.len() < 8 && b"\x93NUMPY".starts_with(&bytes[..bytes.len().min(6)]) {
            NpyErrorKind::Truncated("magic")
        } else {
            NpyErrorKind::NotNpy
        });
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (len_bytes, utf8) = match (major, minor) {
        (1, 0) => (2, false),
        (2, 0) => (4, false),
        (3, 0) => (4, true),
        _ => return Err(NpyErrorKind::Version(major, minor)),
    };
    let len_end = 8 + len_bytes;
    let len_field = bytes.get(8..len_end).ok_or(NpyErrorKind::Truncated("header length"))?;
    let header_len =
        if len_bytes == 2 { u16_le(len_field, 0) as usize } else { u32_le(len_field, 0) as usize };
    if header_len > MAX_HEADER_BYTES {
        return Err(NpyErrorKind::Header(format!("{header_len} bytes long (at most {MAX_HEADER_BYTES})")));
    }
    let header_end = len_end.checked_add(header_len).ok_or(NpyErrorKind::Truncated("header"))?;
    let header = bytes.get(len_end..header_end).ok_or(NpyErrorKind::Truncated("header"))?;
    let header = if utf8 {
        std::str::from_utf8(header).map_err(|_| NpyErrorKind::Header("not UTF-8".into()))?
    } else {
        if !header.is_ascii() {
            return Err(NpyErrorKind::Header("not ASCII".into()));
        }
        std::str::from_utf8(header).map_err(|_| NpyErrorKind::Header("not ASCII".into()))?
    };
    let h = parse_header(header)?;
    let (itemsize, big_endian) = match h.descr.as_str() {
        "<f8" => (8usize, false),
        "<f4" => (4, false),
        ">f8" => (8, true),
        ">f4" => (4, true),
        d => return Err(NpyErrorKind::Dtype(d.to_string())),
    };
    let data = &bytes[header_end..];
    let mut count: u128 = 1;
    for &n in &h.shape {
        count = count.saturating_mul(n as u128);
    }
    let expected = count.saturating_mul(itemsize as u128);
    if expected != data.len() as u128 {
        return Err(NpyErrorKind::DataLength { expected, found: data.len() });
    }
    let values: Vec<f64> = data
        .chunks_exact(itemsize)
        .map(|c| match (itemsize, big_endian) {
            (8, false) => f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]),
            (8, true) => f64::from_be_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]),
            (_, false) => f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            (_, true) => f64::from(f32::from_be_bytes([c[0], c[1], c[2], c[3]])),
        })
        .collect();
    let data = if h.fortran && h.shape.len() > 1 { fortran_to_c(&values, &h.shape) } else { values };
    Ok(NpyArray { shape: h.shape, data })
}

/// Column-major values of `shape` to row-major.
fn fortran_to_c(values: &[f64], shape: &[usize]) -> Vec<f64> {
    let d = shape.len();
    // Strides of the Fortran layout: the first index fastest.
    let mut fstride = vec![1usize; d];
    for i in 1..d {
        fstride[i] = fstride[i - 1] * shape[i - 1];
    }
    let mut out = Vec::with_capacity(values.len());
    let mut idx = vec![0usize; d];
    for _ in 0..values.len() {
        let src: usize = idx.iter().zip(&fstride).map(|(i, s)| i * s).sum();
        out.push(values.get(src).copied().unwrap_or(f64::NAN));
        // Next C-order multi-index: the last index fastest.
        for j in (0..d).rev() {
            idx[j] += 1;
            if idx[j] < shape[j] {
                break;
            }
            idx[j] = 0;
        }
    }
    out
}

struct Header {
    descr: String,
    fortran: bool,
    shape: Vec<usize>,
}

/// The header's dict: `{'descr': '<f8', 'fortran_order': False, 'shape': (8192, 3), }`, with
/// either quote, any whitespace, keys in any order, a trailing comma or none.
fn parse_header(text: &str) -> Result<Header, NpyErrorKind> {
    let bad = |what: &str| NpyErrorKind::Header(what.to_string());
    let mut p = Lexer { s: text.trim_end_matches(['\n', ' ', '\0']).as_bytes(), i: 0 };
    p.expect(b'{').ok_or_else(|| bad("no '{'"))?;
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    loop {
        p.skip_ws();
        if p.eat(b'}') {
            break;
        }
        let key = p.string().ok_or_else(|| bad("a key is not a quoted string"))?;
        p.expect(b':').ok_or_else(|| bad("no ':' after a key"))?;
        p.skip_ws();
        match key.as_str() {
            "descr" => {
                descr = Some(
                    p.string()
                        .ok_or_else(|| bad("'descr' is not a string (structured types are not read)"))?,
                )
            }
            "fortran_order" => {
                fortran = Some(if p.word("True") {
                    true
                } else if p.word("False") {
                    false
                } else {
                    return Err(bad("'fortran_order' is neither True nor False"));
                })
            }
            "shape" => shape = Some(p.tuple().ok_or_else(|| bad("'shape' is not a tuple of integers"))?),
            other => return Err(NpyErrorKind::Header(format!("unknown key {other:?}"))),
        }
        p.skip_ws();
        if !p.eat(b',') {
            p.expect(b'}').ok_or_else(|| bad("no ',' or '}' after a value"))?;
            break;
        }
    }
    p.skip_ws();
    if p.i != p.s.len() {
        return Err(bad("text after the '}'"));
    }
    Ok(Header {
        descr: descr.ok_or_else(|| bad("no 'descr'"))?,
        fortran: fortran.ok_or_else(|| bad("no 'fortran_order'"))?,
        shape: shape.ok_or_else(|| bad("no 'shape'"))?,
    })
}

struct Lexer<'a> {
    s: &'a [u8],
    i: usize,
}

impl Lexer<'_> {
    fn skip_ws(&mut self) {
        while self.s.get(self.i).is_some_and(|c| c.is_ascii_whitespace()) {
            self.i += 1;
        }
    }
    fn eat(&mut self, c: u8) -> bool {
        if self.s.get(self.i) == Some(&c) {
            self.i += 1;
            true
        } else {
            false
        }
    }
    fn expect(&mut self, c: u8) -> Option<()> {
        self.skip_ws();
        self.eat(c).then_some(())
    }
    fn word(&mut self, w: &str) -> bool {
        if self.s[self.i..].starts_with(w.as_bytes()) {
            self.i += w.len();
            true
        } else {
            false
        }
    }
    fn string(&mut self) -> Option<String> {
        self.skip_ws();
        let q = *self.s.get(self.i)?;
        if q != b'\'' && q != b'"' {
            return None;
        }
        let start = self.i + 1;
        let len = self.s.get(start..)?.iter().position(|&c| c == q)?;
        self.i = start + len + 1;
        String::from_utf8(self.s[start..start + len].to_vec()).ok()
    }
    fn tuple(&mut self) -> Option<Vec<usize>> {
        self.skip_ws();
        if !self.eat(b'(') {
            return None;
        }
        let mut dims = Vec::new();
        loop {
            self.skip_ws();
            if self.eat(b')') {
                return Some(dims);
            }
            let start = self.i;
            while self.s.get(self.i).is_some_and(u8::is_ascii_digit) {
                self.i += 1;
            }
            // NumPy 1.x wrote long integers as `8192L`.
            let digits = std::str::from_utf8(&self.s[start..self.i]).ok()?;
            let n: usize = digits.parse().ok()?;
            self.eat(b'L');
            dims.push(n);
            if dims.len() > MAX_DIMS {
                return None;
            }
            self.skip_ws();
            if !self.eat(b',') {
                self.skip_ws();
                return self.eat(b')').then_some(dims);
            }
        }
    }
}

fn u16_le(b: &[u8], at: usize) -> u16 {
    match b.get(at..at + 2) {
        Some(s) => u16::from_le_bytes([s[0], s[1]]),
        None => 0,
    }
}

fn u32_le(b: &[u8], at: usize) -> u32 {
    match b.get(at..at + 4) {
        Some(s) => u32::from_le_bytes([s[0], s[1], s[2], s[3]]),
        None => 0,
    }
}

fn u64_le(b: &[u8], at: usize) -> u64 {
    match b.get(at..at + 8) {
        Some(s) => u64::from_le_bytes([s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]]),
        None => 0,
    }
}

/// Bytes `[at, at + len)` of `b`, or a zip error naming `what`.
fn slice<'a>(b: &'a [u8], at: u64, len: u64, what: &str) -> Result<&'a [u8], NpyErrorKind> {
    let end = at.checked_add(len).ok_or_else(|| NpyErrorKind::Zip(format!("{what} out of range")))?;
    let (at, end) = (usize::try_from(at), usize::try_from(end));
    match (at, end) {
        (Ok(a), Ok(e)) if e <= b.len() => Ok(&b[a..e]),
        _ => Err(NpyErrorKind::Zip(format!("{what} lies beyond the end of the file"))),
    }
}

/// One member of the central directory.
struct Entry {
    name: String,
    method: u16,
    flags: u16,
    crc: u32,
    compressed: u64,
    uncompressed: u64,
    local_offset: u64,
}

/// Parses the bytes of a `.npz` archive: every member, named without `.npy`.
pub fn parse_npz(bytes: &[u8]) -> Result<Vec<(String, NpyArray)>, NpyErrorKind> {
    let entries = central_directory(bytes)?;
    let mut out = Vec::with_capacity(entries.len());
    for e in entries {
        let data = member_bytes(bytes, &e)?;
        let arr = parse_npy(&data)
            .map_err(|kind| NpyErrorKind::InMember { member: e.name.clone(), kind: Box::new(kind) })?;
        let name = e.name.strip_suffix(".npy").unwrap_or(&e.name).to_string();
        out.push((name, arr));
    }
    Ok(out)
}

/// The member `name` (without `.npy`) of a `.npz` archive.
pub fn npz_member(members: Vec<(String, NpyArray)>, name: &str) -> Result<NpyArray, NpyErrorKind> {
    let found = members.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(", ");
    members
        .into_iter()
        .find(|(n, _)| n == name)
        .map(|(_, a)| a)
        .ok_or_else(|| NpyErrorKind::NoMember { name: name.to_string(), found })
}

fn central_directory(b: &[u8]) -> Result<Vec<Entry>, NpyErrorKind> {
    const EOCD: u32 = 0x0605_4b50;
    if b.len() < 22 {
        return Err(NpyErrorKind::Zip("shorter than an end-of-directory record".into()));
    }
    // The end-of-central-directory record is in the last 22 + 65535 bytes.
    let lowest = b.len().saturating_sub(22 + 65_535);
    let eocd = (lowest..=b.len() - 22)
        .rev()
        .find(|&i| u32_le(b, i) == EOCD)
        .ok_or_else(|| NpyErrorKind::Zip("no end-of-central-directory record".into()))?;
    let mut count = u64::from(u16_le(b, eocd + 10));
    let mut cd_size = u64::from(u32_le(b, eocd + 12));
    let mut cd_offset = u64::from(u32_le(b, eocd + 16));
    if (count == 0xFFFF || cd_size == 0xFFFF_FFFF || cd_offset == 0xFFFF_FFFF) && eocd >= 20 {
        // ZIP64: the locator just before the record points at the ZIP64 record.
        let loc = eocd - 20;
        if u32_le(b, loc) == 0x0706_4b50 {
            let z = u64_le(b, loc + 8);
            let rec = slice(b, z, 56, "ZIP64 end-of-directory record")?;
            if u32_le(rec, 0) != 0x0606_4b50 {
                return Err(NpyErrorKind::Zip("bad ZIP64 end-of-directory record".into()));
            }
            count = u64_le(rec, 32);
            cd_size = u64_le(rec, 40);
            cd_offset = u64_le(rec, 48);
        }
    }
    let cd = slice(b, cd_offset, cd_size, "central directory")?;
    // Each entry takes at least 46 bytes: a count beyond that is a lie.
    if count > (cd.len() / 46) as u64 {
        return Err(NpyErrorKind::Zip(format!("{count} members claimed in a {}-byte directory", cd.len())));
    }
    let mut entries = Vec::with_capacity(count as usize);
    let mut at = 0usize;
    for _ in 0..count {
        let h = cd.get(at..at + 46).ok_or_else(|| NpyErrorKind::Zip("central directory cut short".into()))?;
        if u32_le(h, 0) != 0x0201_4b50 {
            return Err(NpyErrorKind::Zip("bad central directory entry".into()));
        }
        let flags = u16_le(h, 8);
        let method = u16_le(h, 10);
        let crc = u32_le(h, 16);
        let mut compressed = u64::from(u32_le(h, 20));
        let mut uncompressed = u64::from(u32_le(h, 24));
        let (n, x, c) = (u16_le(h, 28) as usize, u16_le(h, 30) as usize, u16_le(h, 32) as usize);
        let mut local_offset = u64::from(u32_le(h, 42));
        let name = cd
            .get(at + 46..at + 46 + n)
            .ok_or_else(|| NpyErrorKind::Zip("central directory cut short".into()))?;
        let name = String::from_utf8_lossy(name).into_owned();
        let extra = cd
            .get(at + 46 + n..at + 46 + n + x)
            .ok_or_else(|| NpyErrorKind::Zip("central directory cut short".into()))?;
        // ZIP64 extended information: the 64-bit values of the fields set to 0xFFFFFFFF.
        let mut e = 0usize;
        while e + 4 <= extra.len() {
            let (id, len) = (u16_le(extra, e), u16_le(extra, e + 2) as usize);
            let body = extra.get(e + 4..e + 4 + len).unwrap_or(&[]);
            if id == 0x0001 {
                let mut k = 0usize;
                for field in [&mut uncompressed, &mut compressed, &mut local_offset] {
                    if *field == 0xFFFF_FFFF && k + 8 <= body.len() {
                        *field = u64_le(body, k);
                        k += 8;
                    }
                }
            }
            e += 4 + len;
        }
        entries.push(Entry { name, method, flags, crc, compressed, uncompressed, local_offset });
        at += 46 + n + x + c;
    }
    Ok(entries)
}

fn member_bytes(b: &[u8], e: &Entry) -> Result<Vec<u8>, NpyErrorKind> {
    let in_member = |kind| NpyErrorKind::InMember { member: e.name.clone(), kind: Box::new(kind) };
    if e.flags & 1 != 0 {
        return Err(in_member(NpyErrorKind::Zip("encrypted".into())));
    }
    let local = slice(b, e.local_offset, 30, "local header").map_err(in_member)?;
    if u32_le(local, 0) != 0x0403_4b50 {
        return Err(in_member(NpyErrorKind::Zip("bad local header".into())));
    }
    let skip = 30 + u64::from(u16_le(local, 26)) + u64::from(u16_le(local, 28));
    let start =
        e.local_offset.checked_add(skip).ok_or_else(|| in_member(NpyErrorKind::Zip("bad offset".into())))?;
    let raw = slice(b, start, e.compressed, "member data").map_err(in_member)?;
    if e.uncompressed > MAX_MEMBER_BYTES as u64 {
        return Err(NpyErrorKind::TooLarge { member: e.name.clone() });
    }
    let data = match e.method {
        0 => raw.to_vec(),
        8 => miniz_oxide::inflate::decompress_to_vec_with_limit(raw, MAX_MEMBER_BYTES).map_err(|x| {
            if matches!(x.status, miniz_oxide::inflate::TINFLStatus::HasMoreOutput) {
                NpyErrorKind::TooLarge { member: e.name.clone() }
            } else {
                in_member(NpyErrorKind::Zip(format!("deflate stream is corrupt ({:?})", x.status)))
            }
        })?,
        m => return Err(in_member(NpyErrorKind::Method(m))),
    };
    if data.len() as u64 != e.uncompressed {
        return Err(in_member(NpyErrorKind::Zip(format!(
            "{} bytes after inflating, the directory says {}",
            data.len(),
            e.uncompressed
        ))));
    }
    if crc32(&data) != e.crc {
        return Err(NpyErrorKind::Crc { member: e.name.clone() });
    }
    Ok(data)
}

/// CRC-32 (IEEE 802.3, reflected, polynomial `0xEDB88320`), as zip uses.
fn crc32(data: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut t = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
                k += 1;
            }
            t[i] = c;
            i += 1;
        }
        t
    };
    let mut c = !0u32;
    for &x in data {
        c = TABLE[((c ^ u32::from(x)) & 0xFF) as usize] ^ (c >> 8);
    }
    !c
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn npy(header: &str, major: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = b"\x93NUMPY".to_vec();
        f.push(major);
        f.push(0);
        if major == 1 {
            f.extend_from_slice(&(header.len() as u16).to_le_bytes());
        } else {
            f.extend_from_slice(&(header.len() as u32).to_le_bytes());
        }
        f.extend_from_slice(header.as_bytes());
        f.extend_from_slice(payload);
        f
    }

    fn f8(v: &[f64]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    #[test]
    fn versions_orders_and_types() {
        let c = npy(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }\n",
            1,
            &f8(&[0., 1., 2., 3., 4., 5.]),
        );
        let a = parse_npy(&c).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.get(&[1, 0]), Some(3.0));
        // The same array in Fortran order: columns first.
        let f = npy(
            "{\"descr\":\"<f8\",\"fortran_order\":True,\"shape\":(2,3)}",
            2,
            &f8(&[0., 3., 1., 4., 2., 5.]),
        );
        assert_eq!(parse_npy(&f).unwrap(), a);
        let f4: Vec<u8> = [0.5f32, -1.25].iter().flat_map(|x| x.to_le_bytes()).collect();
        let g = npy("{'descr': '<f4', 'fortran_order': False, 'shape': (2,), }", 3, &f4);
        assert_eq!(parse_npy(&g).unwrap().data, vec![0.5, -1.25]);
        let s = npy("{'descr': '<f8', 'fortran_order': False, 'shape': (), }", 1, &f8(&[7.0]));
        assert_eq!(parse_npy(&s).unwrap().data, vec![7.0]);
        let big: Vec<u8> = 2.0f64.to_be_bytes().to_vec();
        let b = npy("{'descr': '>f8', 'fortran_order': False, 'shape': (1,), }", 1, &big);
        assert_eq!(parse_npy(&b).unwrap().data, vec![2.0]);
    }

    #[test]
    fn errors_say_what() {
        let short = npy("{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }", 1, &f8(&[1.0]));
        let e = parse_npy(&short).unwrap_err().to_string();
        assert!(e.contains("needs 24 bytes"), "{e}");
        let int = npy("{'descr': '<i8', 'fortran_order': False, 'shape': (1,), }", 1, &f8(&[1.0]));
        assert!(
            parse_npy(&int).unwrap_err().to_string().contains("'<i8'")
                || matches!(parse_npy(&int), Err(NpyErrorKind::Dtype(_)))
        );
        let huge =
            npy("{'descr': '<f8', 'fortran_order': False, 'shape': (99999999999, 99999999999), }", 1, &[]);
        assert!(matches!(parse_npy(&huge), Err(NpyErrorKind::DataLength { .. })));
        let e = NpyError { source: "u.npy".into(), kind: NpyErrorKind::NotNpy };
        assert_eq!(e.to_string(), "u.npy: not a NumPy .npy file (no \\x93NUMPY magic)");
    }

    /// A stored (uncompressed) zip of the members, ZIP64-free, as a reference writer.
    fn zip_stored(members: &[(&str, Vec<u8>)]) -> Vec<u8> {
        let mut out = Vec::new();
        let mut cd = Vec::new();
        for (name, data) in members {
            let off = out.len() as u32;
            let crc = crc32(data);
            out.extend_from_slice(&0x0403_4b50u32.to_le_bytes());
            out.extend_from_slice(&[20, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
            out.extend_from_slice(&crc.to_le_bytes());
            out.extend_from_slice(&(data.len() as u32).to_le_bytes());
            out.extend_from_slice(&(data.len() as u32).to_le_bytes());
            out.extend_from_slice(&(name.len() as u16).to_le_bytes());
            out.extend_from_slice(&0u16.to_le_bytes());
            out.extend_from_slice(name.as_bytes());
            out.extend_from_slice(data);
            cd.extend_from_slice(&0x0201_4b50u32.to_le_bytes());
            cd.extend_from_slice(&[20, 0, 20, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
            cd.extend_from_slice(&crc.to_le_bytes());
            cd.extend_from_slice(&(data.len() as u32).to_le_bytes());
            cd.extend_from_slice(&(data.len() as u32).to_le_bytes());
            cd.extend_from_slice(&(name.len() as u16).to_le_bytes());
            cd.extend_from_slice(&[0; 12]);
            cd.extend_from_slice(&off.to_le_bytes());
            cd.extend_from_slice(name.as_bytes());
        }
        let cd_off = out.len() as u32;
        out.extend_from_slice(&cd);
        out.extend_from_slice(&0x0605_4b50u32.to_le_bytes());
        out.extend_from_slice(&[0, 0, 0, 0]);
        out.extend_from_slice(&(members.len() as u16).to_le_bytes());
        out.extend_from_slice(&(members.len() as u16).to_le_bytes());
        out.extend_from_slice(&(cd.len() as u32).to_le_bytes());
        out.extend_from_slice(&cd_off.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out
    }

    #[test]
    fn npz_stored_and_deflated() {
        let a = npy("{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }", 1, &f8(&[1., 2., 3.]));
        let z = zip_stored(&[("u.npy", a.clone()), ("y.npy", a.clone())]);
        let m = parse_npz(&z).unwrap();
        assert_eq!(m.len(), 2);
        assert_eq!(m[1].0, "y");
        assert_eq!(m[1].1.data, vec![1., 2., 3.]);
        // Deflate: re-write the member with method 8.
        let deflated = miniz_oxide::deflate::compress_to_vec(&a, 6);
        let mut z2 = zip_stored(&[("u.npy", deflated.clone())]);
        // Patch method (8), the uncompressed size and the CRC of the raw member.
        let crc = crc32(&a).to_le_bytes();
        z2[8] = 8;
        z2[14..18].copy_from_slice(&crc);
        z2[22..26].copy_from_slice(&(a.len() as u32).to_le_bytes());
        let cd = 30 + 5 + deflated.len();
        z2[cd + 10] = 8;
        z2[cd + 16..cd + 20].copy_from_slice(&crc);
        z2[cd + 24..cd + 28].copy_from_slice(&(a.len() as u32).to_le_bytes());
        let m = parse_npz(&z2).unwrap();
        assert_eq!(m[0].1.data, vec![1., 2., 3.]);
        // A flipped data byte is caught by the CRC.
        let mut bad = zip_stored(&[("u.npy", a)]);
        let last = 30 + 5 + 60;
        bad[last] ^= 0x40;
        assert!(parse_npz(&bad).is_err());
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
            let _ = parse_npy(&bytes);
            let _ = parse_npz(&bytes);
        }

        #[test]
        fn mutated_files_never_panic(pos in 0usize..200, val in any::<u8>(), cut in 0usize..200) {
            let a = npy("{'descr': '<f8', 'fortran_order': True, 'shape': (2, 2), }", 1, &f8(&[1., 2., 3., 4.]));
            let mut z = zip_stored(&[("a.npy", a.clone())]);
            let mut b = a;
            let p = pos % b.len();
            b[p] = val;
            b.truncate(b.len() - cut % b.len());
            let _ = parse_npy(&b);
            let p = pos % z.len();
            z[p] = val;
            let _ = parse_npz(&z);
            z.truncate(z.len() - cut % z.len());
            let _ = parse_npz(&z);
        }
    }
}
