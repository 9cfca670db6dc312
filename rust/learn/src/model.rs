//! The networks: a ResNet of BasicBlocks over a 4-channel RGBD image, then three stride-2
//! transposed convolutions and a 1×1 convolution (Simple Baselines' design, as kPAM and the paper
//! use it). The keypoint network (paper step 4) reads its D output channels as ONE 3D heatmap of
//! shape (D, H/4, W/4): "a corner is here".

use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, PaddingConfig2d};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::config::{Backbone, NetworkConfig};

/// Two 3×3 convolutions with a residual connection (ResNet-18/34's block).
#[derive(Module, Debug)]
pub struct BasicBlock {
    conv1: Conv2d,
    bn1: BatchNorm,
    conv2: Conv2d,
    bn2: BatchNorm,
    /// 1×1 strided convolution + batch norm when the block changes resolution or width.
    downsample: Option<(Conv2d, BatchNorm)>,
}

fn conv(channels: [usize; 2], kernel: usize, stride: usize, device: &Device) -> Conv2d {
    let pad = kernel / 2;
    Conv2dConfig::new(channels, [kernel, kernel])
        .with_stride([stride, stride])
        .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
        .with_bias(false)
        .init(device)
}

impl BasicBlock {
    fn new(in_channels: usize, out_channels: usize, stride: usize, device: &Device) -> Self {
        let downsample = (stride != 1 || in_channels != out_channels).then(|| {
            (
                conv([in_channels, out_channels], 1, stride, device),
                BatchNormConfig::new(out_channels).init(device),
            )
        });
        Self {
            conv1: conv([in_channels, out_channels], 3, stride, device),
            bn1: BatchNormConfig::new(out_channels).init(device),
            conv2: conv([out_channels, out_channels], 3, 1, device),
            bn2: BatchNormConfig::new(out_channels).init(device),
            downsample,
        }
    }

    fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        let identity = match &self.downsample {
            Some((conv, bn)) => bn.forward(conv.forward(input.clone())),
            None => input.clone(),
        };
        let x = relu(self.bn1.forward(self.conv1.forward(input)));
        let x = self.bn2.forward(self.conv2.forward(x));
        relu(x + identity)
    }
}

/// One transposed convolution of the head: ×2 resolution, batch norm, ReLU.
#[derive(Module, Debug)]
pub struct UpBlock {
    deconv: ConvTranspose2d,
    bn: BatchNorm,
}

impl UpBlock {
    fn new(in_channels: usize, out_channels: usize, device: &Device) -> Self {
        Self {
            deconv: ConvTranspose2dConfig::new([in_channels, out_channels], [4, 4])
                .with_stride([2, 2])
                .with_padding([1, 1])
                .with_bias(false)
                .init(device),
            bn: BatchNormConfig::new(out_channels).init(device),
        }
    }

    fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        relu(self.bn.forward(self.deconv.forward(input)))
    }
}

/// RGBD `[batch, 4, H, W]` → `[batch, C, H/4, W/4]`; H and W multiples of 32.
#[derive(Module, Debug)]
pub struct ResNetDeconv {
    stem_conv: Conv2d,
    stem_bn: BatchNorm,
    stem_pool: MaxPool2d,
    stages: Vec<BasicBlock>,
    head: Vec<UpBlock>,
    output: Conv2d,
}

/// The keypoint network: a crop `[batch, 4, S, S]` → heatmap `[batch, D, S/4, S/4]`.
pub type KeypointNet = ResNetDeconv;

impl ResNetDeconv {
    /// The keypoint network of `config`: D = `depth_bins` output channels.
    pub fn keypoints(config: &NetworkConfig, device: &Device) -> Self {
        Self::new(config.backbone, config.depth_bins, device)
    }

    pub fn new(backbone: Backbone, out_channels: usize, device: &Device) -> Self {
        let layout = backbone.layout();
        let mut stages = Vec::new();
        let mut channels = layout.widths[0];
        for (stage, (&width, &blocks)) in layout.widths.iter().zip(&layout.blocks).enumerate() {
            for block in 0..blocks {
                let stride = if stage > 0 && block == 0 { 2 } else { 1 };
                stages.push(BasicBlock::new(channels, width, stride, device));
                channels = width;
            }
        }
        let mut head = Vec::new();
        for _ in 0..3 {
            head.push(UpBlock::new(channels, layout.head_channels, device));
            channels = layout.head_channels;
        }
        Self {
            stem_conv: Conv2dConfig::new([4, layout.widths[0]], [7, 7])
                .with_stride([2, 2])
                .with_padding(PaddingConfig2d::Explicit(3, 3, 3, 3))
                .with_bias(false)
                .init(device),
            stem_bn: BatchNormConfig::new(layout.widths[0]).init(device),
            stem_pool: MaxPool2dConfig::new([3, 3])
                .with_strides([2, 2])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(),
            stages,
            head,
            output: Conv2dConfig::new([channels, out_channels], [1, 1]).init(device),
        }
    }

    pub fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        let mut x = self
            .stem_pool
            .forward(relu(self.stem_bn.forward(self.stem_conv.forward(input))));
        for block in &self.stages {
            x = block.forward(x);
        }
        for up in &self.head {
            x = up.forward(x);
        }
        self.output.forward(x)
    }
}
