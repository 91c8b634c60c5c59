//! The `kiss_decoder` target's input: `k` (1 byte, `% 16` chunk-size bytes follow), the
//! chunk sizes (each `% 64`, 0 standing for 64; used in turn), then the byte stream.

/// Split an input into its chunk sizes and its stream.
pub fn split(data: &[u8]) -> (Vec<usize>, &[u8]) {
    let Some((&k, rest)) = data.split_first() else {
        return (vec![1], &[]);
    };
    let k = usize::from(k % 16).min(rest.len());
    let (sizes, stream) = rest.split_at(k);
    let mut sizes: Vec<usize> = sizes
        .iter()
        .map(|&s| match usize::from(s % 64) {
            0 => 64,
            n => n,
        })
        .collect();
    if sizes.is_empty() {
        sizes.push(1);
    }
    (sizes, stream)
}

/// The input that feeds `stream` in chunks of `sizes` (each 1..=64, at most 15 of them).
pub fn join(sizes: &[u8], stream: &[u8]) -> Vec<u8> {
    assert!(sizes.len() < 16 && sizes.iter().all(|&s| (1..=64).contains(&s)));
    let mut out = vec![sizes.len() as u8];
    out.extend(sizes.iter().map(|&s| s % 64));
    out.extend_from_slice(stream);
    out
}
