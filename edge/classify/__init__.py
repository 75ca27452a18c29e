"""Classification: features, weighted k-NN, ONNX export and inference."""
