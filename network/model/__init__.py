"""The network itself: ResNet-18 encoder, ConvLSTM slot memory, shelf-anchored top/front decoders,
discriminators, and the camera-motion read that aligns the memory."""
