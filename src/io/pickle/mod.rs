//! A minimal, safe Python pickle reader for NumPy arrays.
//!
//! Supports the opcodes of protocols 0-5 that plain data uses (ints, floats, strings, bytes,
//! tuples, lists, dicts, sets, memo), plus exactly the globals NumPy needs to rebuild a
//! float array: `numpy.(_)core.multiarray._reconstruct`, `numpy.ndarray`, `numpy.dtype`,
//! `numpy.(_)core.numeric._frombuffer` (protocol 5), `_codecs.encode` (protocol 2 bytes) and
//! `collections.OrderedDict`. Any other global is refused: nothing is ever executed.
//!
//! Two file shapes are read:
//! - a pickled dict of float arrays (the GeoTransformer feature `.pkl` files of the C-GenReg
//!   reference: `ref_points_f (Nr,3)`, `ref_feats_f (Nr,256)`, `src_points_f`, `src_feats_f`);
//! - a legacy (non-zip) PyTorch `torch.save` of a NumPy array (Predator / RegTR `.pth`):
//!   5 concatenated pickles (magic number, protocol version 1001, sys info, the object,
//!   storage keys); the 4th is the array. Torch tensors (persistent storages) are refused.
//!
//! Array values keep their dtype (float32 / float64) and are returned in C order; clouds are
//! (N,3) x,y,z in metres.

mod vm;

use super::npy::{array_to_cloud, decode_array, shape_str, NpyArray};
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use std::collections::BTreeMap;
use std::path::Path;
use vm::{PyArray, Value, Vm, TORCH_MAGIC};

fn to_npy(path: &Path, field: &str, a: &PyArray) -> Result<NpyArray> {
    match (&a.dtype, &a.data) {
        (Some(dt), Some(data)) => decode_array(
            path,
            field,
            (dt.kind, dt.size, dt.big),
            &a.shape,
            a.fortran,
            data,
        ),
        _ => Err(Error::format(
            path,
            field,
            "an ndarray with its state set",
            "an incomplete ndarray",
        )),
    }
}

/// Parse a pickled dict of arrays; keys must be strings. Float arrays are returned; values
/// that are not float arrays (ints, strings, integer arrays) are skipped.
pub fn parse_pickle_arrays(path: &Path, bytes: &[u8]) -> Result<BTreeMap<String, NpyArray>> {
    let mut vm = Vm::new(path, bytes);
    let v = vm.run()?;
    let Value::Dict(_, items) = v else {
        return Err(Error::format(
            path,
            "pickle",
            "a dict of arrays",
            v.type_name(),
        ));
    };
    let mut out = BTreeMap::new();
    for (k, v) in items {
        let (Value::Str(k), Value::Array(_, a)) = (&k, &v) else {
            continue;
        };
        if a.dtype.is_some_and(|d| d.kind != 'f') {
            continue;
        }
        out.insert(k.to_string(), to_npy(path, k, a)?);
    }
    if out.is_empty() {
        return Err(Error::format(
            path,
            "pickle",
            "a dict with at least one float array",
            "no float arrays",
        ));
    }
    Ok(out)
}

pub fn read_pickle_arrays(path: &Path) -> Result<BTreeMap<String, NpyArray>> {
    let bytes = crate::io::limits::read_file(path)?;
    parse_pickle_arrays(path, &bytes)
}

/// Parse a legacy `torch.save` of a NumPy array (or a plain pickle of one array).
pub fn parse_pth_array(path: &Path, bytes: &[u8]) -> Result<NpyArray> {
    if bytes.starts_with(b"PK\x03\x04") {
        return Err(Error::format(
            path,
            "format",
            "a legacy (non-zip) torch.save of a NumPy array",
            "a zip-based torch.save archive (save a NumPy array with \
             _use_new_zipfile_serialization=False, or export .npy)",
        ));
    }
    let mut vm = Vm::new(path, bytes);
    let first = vm.run()?;
    let obj = match first {
        Value::Int(TORCH_MAGIC) => {
            let mut obj = None;
            for k in 1..5 {
                vm.index = k;
                let v = vm.run()?;
                match k {
                    1 if !matches!(v, Value::Int(1001)) => {
                        return Err(vm.err("torch protocol version 1001", format!("{v:?}")))
                    }
                    3 => obj = Some(v),
                    4 if !matches!(&v, Value::List(_, l) if l.is_empty()) => {
                        return Err(vm.err(
                            "an empty storage list (NumPy data only)",
                            "torch tensor storages",
                        ))
                    }
                    _ => {}
                }
            }
            obj.unwrap_or(Value::None)
        }
        other => other,
    };
    match obj {
        Value::Array(_, a) => to_npy(path, "array", &a),
        other => Err(Error::format(
            path,
            "object",
            "a numpy.ndarray",
            other.type_name(),
        )),
    }
}

pub fn read_pth_array(path: &Path) -> Result<NpyArray> {
    let bytes = crate::io::limits::read_file(path)?;
    parse_pth_array(path, &bytes)
}

/// An (N,3) `.pth` array as a cloud.
pub fn read_pth_points(path: &Path) -> Result<PointCloud> {
    let a = read_pth_array(path)?;
    if !matches!(a.shape[..], [_, 3]) {
        return Err(Error::format(
            path,
            "array shape",
            "(N, 3)",
            shape_str(&a.shape),
        ));
    }
    array_to_cloud(path, "array", &a)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::vm::{latin1, raw_unicode_escape, Decoded};
    use super::*;
    use crate::io::npy::NpyData;

    pub(crate) fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    /// `pickle.dumps(d, protocol=p)` by Python 3.11 + NumPy 2.4 of
    /// d = {ref_points_f: arange(6).reshape(2,3)*0.5, ref_feats_f: [[1,0,0,0],[0,-2,0,0]],
    ///      src_points_f: [[.25,.5,.75]], src_feats_f: [[0,0,3.5,0]]}, all float32.
    const GEO_P2: &str = "80027d710028580c0000007265665f706f696e74735f667101636e756d70792e5f636f72652e6d756c746961727261790a5f7265636f6e7374727563740a7102636e756d70790a6e6461727261790a71034b00857104635f636f646563730a656e636f64650a7105580100000062710658060000006c6174696e31710786710852710987710a52710b284b014b024b0386710c636e756d70790a64747970650a710d58020000006634710e898887710f527110284b0358010000003c71114e4e4e4affffffff4affffffff4b0074711262896805581a000000000000000000003f0000c2803f0000c3803f00000040000020407113680786711452711574711662580b0000007265665f66656174735f667117680268034b00857118680987711952711a284b014b024b0486711b681089680558220000000000c2803f00000000000000000000000000000000000000c3800000000000000000711c680786711d52711e74711f62580c0000007372635f706f696e74735f667120680268034b008571216809877122527123284b014b014b038671246810896805580d0000000000c2803e0000003f0000403f7125680786712652712774712862580b0000007372635f66656174735f667129680268034b0085712a680987712b52712c284b014b014b0486712d6810896805581000000000000000000000000000604000000000712e680786712f52713074713162752e";
    pub(crate) const GEO_P4: &str = "8004957d010000000000007d94288c0c7265665f706f696e74735f66948c166e756d70792e5f636f72652e6d756c74696172726179948c0c5f7265636f6e7374727563749493948c056e756d7079948c076e6461727261799493944b0085944301629487945294284b014b024b03869468058c0564747970659493948c02663494898887945294284b038c013c944e4e4e4affffffff4affffffff4b00749462894318000000000000003f0000803f0000c03f0000004000002040947494628c0b7265665f66656174735f6694680468074b008594680987945294284b014b024b04869468118943200000803f00000000000000000000000000000000000000c00000000000000000947494628c0c7372635f706f696e74735f6694680468074b008594680987945294284b014b014b038694681189430c0000803e0000003f0000403f947494628c0b7372635f66656174735f6694680468074b008594680987945294284b014b014b04869468118943100000000000000000000060400000000094749462752e";
    const GEO_P5: &str = "80059559010000000000007d94288c0c7265665f706f696e74735f66948c136e756d70792e5f636f72652e6e756d65726963948c0b5f66726f6d62756666657294939428961800000000000000000000000000003f0000803f0000c03f0000004000002040948c056e756d7079948c0564747970659493948c02663494898887945294284b038c013c944e4e4e4affffffff4affffffff4b007494624b024b0386948c014394749452948c0b7265665f66656174735f66946804289620000000000000000000803f00000000000000000000000000000000000000c0000000000000000094680b4b024b048694680f749452948c0c7372635f706f696e74735f6694680428960c000000000000000000803e0000003f0000403f94680b4b014b038694680f749452948c0b7372635f66656174735f66946804289610000000000000000000000000000000000060400000000094680b4b014b048694680f74945294752e";
    /// protocol 4 of {big: float64 '>f8' [1.5,-2], n: 7, s: 'text', i: arange(3) int64,
    /// fort: asfortranarray(arange(6, float32).reshape(2,3))}.
    const MIXED_P4: &str = "80049573010000000000007d94288c03626967948c166e756d70792e5f636f72652e6d756c74696172726179948c0c5f7265636f6e7374727563749493948c056e756d7079948c076e6461727261799493944b0085944301629487945294284b014b02859468058c0564747970659493948c02663894898887945294284b038c013e944e4e4e4affffffff4affffffff4b007494628943103ff8000000000000c000000000000000947494628c016e944b078c0173948c0474657874948c016994680468074b008594680987945294284b014b038594680e8c02693894898887945294284b038c013c944e4e4e4affffffff4affffffff4b00749462894318000000000000000001000000000000000200000000000000947494628c04666f727494680468074b008594680987945294284b014b024b038694680e8c02663494898887945294284b0368214e4e4e4affffffff4affffffff4b0074946288431800000000000040400000803f00008040000000400000a04094749462752e";

    fn check_geo(m: &BTreeMap<String, NpyArray>) {
        assert_eq!(m.len(), 4);
        assert_eq!(m["ref_points_f"].shape, vec![2, 3]);
        assert_eq!(
            m["ref_points_f"].data,
            NpyData::F32(vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5])
        );
        assert_eq!(m["ref_feats_f"].shape, vec![2, 4]);
        assert_eq!(m["ref_feats_f"].to_f32()[5], -2.0);
        assert_eq!(m["src_points_f"].to_f32(), vec![0.25, 0.5, 0.75]);
        assert_eq!(m["src_feats_f"].to_f32(), vec![0.0, 0.0, 3.5, 0.0]);
    }

    /// `pickle.dumps(d, protocol=0)` of the same dict (UNICODE opcodes, text ints).
    const GEO_P0: &str = "286470300a567265665f706f696e74735f660a70310a636e756d70792e5f636f72652e6d756c746961727261790a5f7265636f6e7374727563740a70320a28636e756d70790a6e6461727261790a70330a2849300a7470340a635f636f646563730a656e636f64650a70350a2856620a70360a566c6174696e310a70370a7470380a5270390a747031300a527031310a2849310a2849320a49330a747031320a636e756d70790a64747970650a7031330a285666340a7031340a4930300a4930310a747031350a527031360a2849330a563c0a7031370a4e4e4e492d310a492d310a49300a747031380a624930300a67350a28565c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030303f5c75303030305c7530303030803f5c75303030305c7530303030c03f5c75303030305c75303030305c7530303030405c75303030305c753030303020400a7031390a67370a747032300a527032310a747032320a6273567265665f66656174735f660a7032330a67320a2867330a2849300a747032340a67390a747032350a527032360a2849310a2849320a49340a747032370a6731360a4930300a67350a28565c75303030305c7530303030803f5c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c7530303030c05c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030300a7032380a67370a747032390a527033300a747033310a6273567372635f706f696e74735f660a7033320a67320a2867330a2849300a747033330a67390a747033340a527033350a2849310a2849310a49330a747033360a6731360a4930300a67350a28565c75303030305c7530303030803e5c75303030305c75303030305c75303030303f5c75303030305c7530303030403f0a7033370a67370a747033380a527033390a747034300a6273567372635f66656174735f660a7034310a67320a2867330a2849300a747034320a67390a747034330a527034340a2849310a2849310a49340a747034350a6731360a4930300a67350a28565c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c753030303060405c75303030305c75303030305c75303030305c75303030300a7034360a67370a747034370a527034380a747034390a62732e";

    #[test]
    fn protocol_0_numpy_pickle() {
        let m = parse_pickle_arrays(Path::new("p0"), &hex(GEO_P0)).unwrap();
        check_geo(&m);
        assert!(matches!(
            raw_unicode_escape(br"a\u00e9\U0001F600\\u"),
            Some(Decoded::Text(t)) if t == "a\u{e9}\u{1F600}\\\\u"
        ));
        assert!(raw_unicode_escape(br"\u12").is_none());
        assert!(raw_unicode_escape(br"\uzzzz").is_none());
    }

    /// A pickle of `levels` nested 1-tuples around an int: `K 0` then `levels` x TUPLE1.
    fn nested_tuples(levels: usize) -> Vec<u8> {
        let mut b = b"\x80\x02K\x00".to_vec();
        b.extend(std::iter::repeat_n(0x85u8, levels));
        b.push(b'.');
        b
    }

    #[test]
    fn deep_nesting_is_a_clear_error_not_a_stack_overflow() {
        // 50,000 levels overflowed the stack when the value was cloned or dropped.
        for bytes in [
            nested_tuples(50_000),
            // Lists through marks: `(` x N then `l` x N.
            {
                let mut b = b"\x80\x02".to_vec();
                b.extend(std::iter::repeat_n(b'(', 50_000));
                b.extend(std::iter::repeat_n(b'l', 50_000));
                b.push(b'.');
                b
            },
            // Empty lists appended into each other: `]` x N then `a` x (N-1).
            {
                let mut b = b"\x80\x02".to_vec();
                b.extend(std::iter::repeat_n(b']', 50_000));
                b.extend(std::iter::repeat_n(b'a', 49_999));
                b.push(b'.');
                b
            },
        ] {
            let e = parse_pickle_arrays(Path::new("deep.pkl"), &bytes)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("deep.pkl") && e.contains("nested at most 1000"),
                "{e}"
            );
            let e = parse_pth_array(Path::new("deep.pth"), &bytes)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("deep.pth") && e.contains("CGENREG_MAX_NESTING"),
                "{e}"
            );
        }
        // Within the limit, nesting is fine (the error is about the shape, not the depth).
        let e = parse_pickle_arrays(Path::new("ok.pkl"), &nested_tuples(900))
            .unwrap_err()
            .to_string();
        assert!(e.contains("a dict of arrays"), "{e}");
        // And through the file readers (the `.pth` cloud path and `--geotransformer-pkl`).
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("deep.pth");
        std::fs::write(&f, nested_tuples(50_000)).unwrap();
        assert!(crate::io::cloud::load_cloud(&f).is_err());
        let f = d.path().join("deep.pkl");
        std::fs::write(&f, nested_tuples(50_000)).unwrap();
        assert!(read_pickle_arrays(&f).is_err());
    }

    #[test]
    fn self_doubling_lists_are_capped() {
        // `]` then (DUP, APPEND) x 60: each step copies the list into itself, 2^60 values.
        let mut b = b"\x80\x02]".to_vec();
        for _ in 0..60 {
            b.extend_from_slice(b"2a");
        }
        b.push(b'.');
        let t = std::time::Instant::now();
        let e = parse_pickle_arrays(Path::new("dbl.pkl"), &b)
            .unwrap_err()
            .to_string();
        assert!(e.contains("values"), "{e}");
        assert!(t.elapsed().as_secs() < 5);
    }

    #[test]
    fn latin1_matches_char_by_char() {
        let s: String = (0u32..256).filter_map(char::from_u32).collect();
        let want: Vec<u8> = s.chars().map(|c| c as u32 as u8).collect();
        assert_eq!(latin1(s.as_bytes()).unwrap(), want);
        assert!(latin1("\u{100}".as_bytes()).is_none());
        assert!(latin1("\u{20ac}".as_bytes()).is_none());
        assert!(latin1(&[0xC3]).is_none());
        assert!(latin1(&[0xC3, 0x41]).is_none());
    }

    #[test]
    fn python_pickles_of_float32_dicts() {
        for (name, h) in [("p2", GEO_P2), ("p4", GEO_P4), ("p5", GEO_P5)] {
            let m = parse_pickle_arrays(Path::new(name), &hex(h)).unwrap();
            check_geo(&m);
        }
        // NumPy 1.x writes `numpy.core.multiarray` (the authors' files): same bytes otherwise.
        let p2 = hex(GEO_P2);
        let from = b"numpy._core.multiarray\n";
        let at = p2.windows(from.len()).position(|w| w == from).unwrap();
        let mut old = p2[..at].to_vec();
        old.extend_from_slice(b"numpy.core.multiarray\n");
        old.extend_from_slice(&p2[at + from.len()..]);
        check_geo(&parse_pickle_arrays(Path::new("old"), &old).unwrap());
    }

    #[test]
    fn big_endian_fortran_and_skipped_values() {
        let m = parse_pickle_arrays(Path::new("mixed"), &hex(MIXED_P4)).unwrap();
        assert_eq!(m.keys().collect::<Vec<_>>(), ["big", "fort"]);
        assert_eq!(m["big"].data, NpyData::F64(vec![1.5, -2.0]));
        assert_eq!(m["fort"].shape, vec![2, 3]);
        assert_eq!(m["fort"].to_f32(), vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    }

    #[test]
    fn refuses_other_globals_and_bad_input() {
        // pickle.dumps(os.system) style: GLOBAL 'os system'.
        let evil = b"\x80\x02cos\nsystem\nq\x00X\x02\x00\x00\x00lsq\x01\x85q\x02Rq\x03.";
        let e = parse_pickle_arrays(Path::new("evil.pkl"), evil)
            .unwrap_err()
            .to_string();
        assert!(e.contains("evil.pkl") && e.contains("os.system"), "{e}");
        let p4 = hex(GEO_P4);
        let e = parse_pickle_arrays(Path::new("cut.pkl"), &p4[..p4.len() / 2])
            .unwrap_err()
            .to_string();
        assert!(e.contains("cut.pkl") && e.contains("truncated"), "{e}");
        let e = parse_pickle_arrays(Path::new("l.pkl"), b"\x80\x02]q\x00.")
            .unwrap_err()
            .to_string();
        assert!(e.contains("a dict of arrays"), "{e}");
        let e = parse_pth_array(Path::new("z.pth"), b"PK\x03\x04rest")
            .unwrap_err()
            .to_string();
        assert!(e.contains("zip"), "{e}");
    }

    #[test]
    fn staged_pth_files() {
        let Some(root) = crate::testing::test_data_root() else {
            return;
        };
        let m = root.join("3dmatch-redkitchen");
        for (rel, n) in [
            ("regtr/cloud_bin_0.pth", 18_977),
            ("regtr/cloud_bin_5.pth", 19_084),
            ("predator-demo/cloud_bin_21.pth", 25_337),
            ("predator-demo/cloud_bin_34.pth", 14_602),
        ] {
            let a = read_pth_array(&m.join(rel)).unwrap();
            assert_eq!(a.shape, vec![n, 3], "{rel}");
            assert!(matches!(a.data, NpyData::F64(_)));
            assert_eq!(read_pth_points(&m.join(rel)).unwrap().len(), n);
        }
        // RegTR's cloud_bin_0 and GeoTransformer's ref.npy are the same downsampled cloud.
        let a = read_pth_array(&m.join("regtr/cloud_bin_0.pth")).unwrap();
        let b = crate::io::npy::read_npy(&m.join("geotransformer-demo/ref.npy")).unwrap();
        assert_eq!(a.shape, b.shape);
        let (mut sa, mut sb) = (a.to_f64(), b.to_f64());
        let key = |v: &mut Vec<f64>| {
            let mut rows: Vec<[f64; 3]> = v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            rows.sort_by(|x, y| x.partial_cmp(y).unwrap());
            *v = rows.concat();
        };
        key(&mut sa);
        key(&mut sb);
        let max = sa
            .iter()
            .zip(&sb)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(max < 1e-6, "max diff {max}");
    }
}
