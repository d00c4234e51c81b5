//! Fresh output buffers written in parallel. A zeroed `Vec` is one serial pass over megabytes
//! on the thread that asks for it, before the parallel work starts (a tenth of the time of
//! the thread that runs a training step); here each chunk is written, or zeroed first where
//! its writer only adds, by the thread that fills it, while it is in that core's cache.

use std::mem::MaybeUninit;

use rayon::prelude::*;

/// `len` values made a chunk of `m` at a time, in parallel: `fill(i, slots)` writes every
/// slot of chunk `i`. `len` must be a multiple of `m`.
pub(crate) fn planes_from(
    len: usize,
    m: usize,
    fill: impl Fn(usize, &mut [MaybeUninit<f32>]) + Sync,
) -> Vec<f32> {
    assert!(
        m > 0 && len.is_multiple_of(m),
        "{len} values in planes of {m}"
    );
    let mut out: Vec<f32> = Vec::with_capacity(len);
    out.spare_capacity_mut()
        .par_chunks_mut(m)
        .enumerate()
        .for_each(|(plane, slots)| fill(plane, slots));
    // SAFETY: `fill` wrote every slot of each of the `len / m` planes.
    unsafe { out.set_len(len) };
    out
}

/// Three buffers of `chunks` chunks each, of `sizes` values a chunk, made in parallel:
/// `fill(i, chunks)` gets chunk `i` of each buffer, zeroed, on the thread that fills it.
pub(crate) fn zeroed_triple(
    chunks: usize,
    sizes: [usize; 3],
    fill: impl Fn(usize, [&mut [f32]; 3]) + Sync,
) -> [Vec<f32>; 3] {
    let mut buffers = sizes.map(|size| Vec::<f32>::with_capacity(chunks * size));
    let [a, b, c] = &mut buffers;
    a.spare_capacity_mut()
        .par_chunks_mut(sizes[0])
        .zip(b.spare_capacity_mut().par_chunks_mut(sizes[1]))
        .zip(c.spare_capacity_mut().par_chunks_mut(sizes[2]))
        .enumerate()
        .for_each(|(i, ((a, b), c))| fill(i, [zeroed(a), zeroed(b), zeroed(c)]));
    for (buffer, size) in buffers.iter_mut().zip(sizes) {
        // SAFETY: every chunk of every buffer was zeroed above.
        unsafe { buffer.set_len(chunks * size) };
    }
    buffers
}

/// `slots` set to zero, as values.
pub(crate) fn zeroed(slots: &mut [MaybeUninit<f32>]) -> &mut [f32] {
    slots.fill(MaybeUninit::new(0.0));
    // SAFETY: every slot was just written, and `MaybeUninit<f32>` has `f32`'s layout.
    unsafe { &mut *(std::ptr::from_mut(slots) as *mut [f32]) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_chunk_is_filled_by_its_writer_and_zeroed_chunks_start_at_zero() {
        let made = planes_from(12, 4, |i, slots| {
            let values = zeroed(slots);
            values[i] += 1.0 + i as f32;
        });
        let want = [1.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0];
        assert_eq!(made, want);
        let [a, b, c] = zeroed_triple(2, [3, 1, 2], |i, [a, _, c]| {
            a[i] = 1.0;
            c[1] = 2.0;
        });
        assert_eq!(
            (a, b, c),
            (
                vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
                vec![0.0; 2],
                vec![0.0, 2.0, 0.0, 2.0]
            )
        );
    }
}
