//! The flat buffers of one optimiser: its variables, their gradients and their moments, each one contiguous buffer.

use super::{Moments, Param};
use tch::Tensor;

/// The variables and their moments, each one contiguous buffer; each variable (and its moments, once it has any) a
/// view of its stretch.
pub(super) struct Flat {
    pub params: Tensor,
    /// The gradients' buffer: after the first step each variable's gradient is a view of its stretch, which autograd
    /// accumulates into in place (a step with no gradient yet, or one autograd replaced, moves them back in).
    pub grads: Tensor,
    pub exp_avg: Tensor,
    pub exp_avg_sq: Tensor,
    /// Each variable's stretch: (offset, length).
    pub stretches: Vec<(i64, i64)>,
}

/// The alignment of each variable's stretch in the flat buffers, in elements (64 bytes of f32).
const ALIGN: i64 = 16;

impl Flat {
    /// Moves `params`' variables into one buffer (each becomes a view of its stretch, with its values) and makes the
    /// moments' buffers.
    pub fn of(params: &mut [Param]) -> Self {
        // Each stretch starts on a 64-byte boundary, as a variable of its own would (libtorch's CPU allocator aligns
        // to 64 bytes): a GEMM's kernel may round differently on an unaligned operand. The padding holds zeros, whose
        // Adam update is zero.
        let stretches: Vec<(i64, i64)> = params
            .iter()
            .scan(0, |offset, p| {
                let len = p.var.numel() as i64;
                let start = *offset;
                *offset = (start + len + ALIGN - 1) / ALIGN * ALIGN;
                Some((start, len))
            })
            .collect();
        let Some(first) = params.first() else {
            let empty = Tensor::zeros([0], (tch::Kind::Float, tch::Device::Cpu));
            return Flat {
                grads: empty.zeros_like(),
                exp_avg: empty.zeros_like(),
                exp_avg_sq: empty.zeros_like(),
                params: empty,
                stretches,
            };
        };
        let kind = first.var.kind();
        let total = stretches.last().map_or(0, |&(offset, len)| offset + len);
        let flat = Tensor::zeros([total], (kind, first.var.device()));
        for (p, &(offset, len)) in params.iter_mut().zip(&stretches) {
            let shape = p.var.size();
            let stretch = flat.narrow(0, offset, len).view(shape.as_slice());
            tch::no_grad(|| stretch.shallow_clone().copy_(&p.var));
            p.var.set_data(&stretch);
        }
        Flat {
            grads: flat.zeros_like(),
            exp_avg: flat.zeros_like(),
            exp_avg_sq: flat.zeros_like(),
            params: flat,
            stretches,
        }
    }

    /// Whether `grads` (one per variable, in order) are the views of the gradients' buffer.
    pub fn holds(&self, grads: &[Tensor]) -> bool {
        let base = self.grads.data_ptr() as usize;
        let width = self.grads.kind().elt_size_in_bytes();
        grads.len() == self.stretches.len()
            && !grads.is_empty()
            && grads
                .iter()
                .zip(&self.stretches)
                .all(|(g, &(offset, len))| {
                    g.defined()
                        && g.data_ptr() as usize == base + offset as usize * width
                        && g.numel() as i64 == len
                        && g.is_contiguous()
                })
    }

    /// Fresh (zero) moments of the variable `var` at its stretch: views of the moments' buffers.
    pub fn moments(&self, var: &Tensor, offset: i64, len: i64) -> Moments {
        let shape = var.size();
        let view = |buffer: &Tensor| {
            let mut v = buffer.narrow(0, offset, len).view(shape.as_slice());
            let _ = tch::no_grad(|| v.zero_());
            v
        };
        Moments {
            step: 0,
            exp_avg: view(&self.exp_avg),
            exp_avg_sq: view(&self.exp_avg_sq),
        }
    }
}
