//! Which burn backend runs the network, picked at run time among those compiled in (burn 0.22's
//! tensors carry their backend in the device, not in their type).

/// The backends boxpose can be built with; `flex` is the default and builds from crates alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum BackendKind {
    /// burn's pure-Rust CPU backend (multi-threaded, SIMD).
    #[default]
    Flex,
    /// GPU through wgpu (Vulkan, Metal, DX12): `cargo build --features boxpose-learn/wgpu`.
    Wgpu,
    /// NVIDIA GPU through CubeCL: `--features boxpose-learn/cuda` (its build downloads LLVM).
    Cuda,
    /// LibTorch on the CPU: `--features boxpose-learn/tch`, see docs/learning.md.
    Tch,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Flex => "flex",
            BackendKind::Wgpu => "wgpu",
            BackendKind::Cuda => "cuda",
            BackendKind::Tch => "tch",
        }
    }

    /// The device of this backend, or an error saying which Cargo feature builds it.
    pub fn device(self) -> Result<burn::tensor::Device, crate::LearnError> {
        let missing = |feature: &str| {
            Err(crate::LearnError::Backend(format!(
                "this binary was built without the {feature} backend: rebuild with `cargo build --release --features boxpose-learn/{feature}`"
            )))
        };
        match self {
            #[cfg(feature = "flex")]
            BackendKind::Flex => Ok(burn::tensor::Device::flex()),
            #[cfg(feature = "wgpu")]
            BackendKind::Wgpu => Ok(burn::tensor::Device::wgpu(Default::default())),
            #[cfg(feature = "cuda")]
            BackendKind::Cuda => Ok(burn::tensor::Device::cuda(0usize)),
            // burn 0.22 deprecates burn-tch in favour of its CubeCL CPU backend, which needs
            // LLVM 23 (not installable here); libtorch is still the fastest CPU backend.
            #[cfg(feature = "tch")]
            #[allow(deprecated)]
            BackendKind::Tch => Ok(burn::tensor::Device::libtorch()),
            #[allow(unreachable_patterns)]
            other => missing(other.name()),
        }
    }
}
