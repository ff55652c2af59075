//! LZF (liblzf's format), the compression of PCD's `binary_compressed` data.

/// LZF decompression (liblzf format, as PCL writes it). Fails on any out-of-range reference
/// or when the output is not exactly `out_len` bytes.
pub fn lzf_decompress(input: &[u8], out_len: usize) -> std::result::Result<Vec<u8>, String> {
    // LZF expands at most ~88x (3 bytes -> 264), which bounds a lying size field.
    let mut out = Vec::with_capacity(out_len.min(input.len().saturating_mul(90)));
    let mut ip = 0;
    while ip < input.len() {
        let ctrl = input[ip] as usize;
        ip += 1;
        if ctrl < 32 {
            let len = ctrl + 1;
            let lit = input
                .get(ip..ip + len)
                .ok_or_else(|| format!("literal run past the end of input at byte {ip}"))?;
            if out.len() + len > out_len {
                return Err("output longer than declared".into());
            }
            out.extend_from_slice(lit);
            ip += len;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                len += *input.get(ip).ok_or("truncated back-reference")? as usize;
                ip += 1;
            }
            len += 2;
            let lo = *input.get(ip).ok_or("truncated back-reference")? as usize;
            ip += 1;
            let dist = ((ctrl & 0x1f) << 8) + lo + 1;
            if dist > out.len() {
                return Err(format!(
                    "back-reference {dist} bytes before the start of the output"
                ));
            }
            if out.len() + len > out_len {
                return Err("output longer than declared".into());
            }
            let start = out.len() - dist;
            if dist >= len {
                out.extend_from_within(start..start + len);
            } else {
                // Overlapping copy repeats the last `dist` bytes.
                for k in 0..len {
                    out.push(out[start + k]);
                }
            }
        }
    }
    if out.len() != out_len {
        return Err(format!(
            "decompressed to {} bytes, header says {out_len}",
            out.len()
        ));
    }
    Ok(out)
}

/// LZF compression (greedy, hash of 3 bytes) in liblzf's format; used to write test files.
pub fn lzf_compress(input: &[u8]) -> Vec<u8> {
    const HLOG: usize = 14;
    let mut table = vec![usize::MAX; 1 << HLOG];
    let mut out = Vec::with_capacity(input.len() + input.len() / 32 + 2);
    let mut lit_start = 0;
    let flush = |out: &mut Vec<u8>, lit: &[u8]| {
        for chunk in lit.chunks(32) {
            out.push((chunk.len() - 1) as u8);
            out.extend_from_slice(chunk);
        }
    };
    let mut i = 0;
    while i + 2 < input.len() {
        let h = ((input[i] as usize) << 16 | (input[i + 1] as usize) << 8 | input[i + 2] as usize)
            .wrapping_mul(2654435761)
            >> 8
            & ((1 << HLOG) - 1);
        let cand = table[h];
        table[h] = i;
        if cand != usize::MAX && i - cand <= 8192 && input[cand..cand + 3] == input[i..i + 3] {
            let max = (input.len() - i).min(264);
            let mut len = 3;
            while len < max && input[cand + len] == input[i + len] {
                len += 1;
            }
            flush(&mut out, &input[lit_start..i]);
            let off = i - cand - 1;
            let l = len - 2;
            if l < 7 {
                out.push(((l << 5) | (off >> 8)) as u8);
            } else {
                out.push(((7 << 5) | (off >> 8)) as u8);
                out.push((l - 7) as u8);
            }
            out.push((off & 0xff) as u8);
            i += len;
            lit_start = i;
        } else {
            i += 1;
        }
    }
    flush(&mut out, &input[lit_start..]);
    out
}
