"""The network itself: ResNet-18 encoder, ConvLSTM slot memory, shelf-anchored top/front decoders,
discriminators, the camera-motion read that aligns the memory, and the frozen CPU graphs its parts run as."""
