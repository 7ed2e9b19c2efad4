"""Neural networks: the cDFCVAE translator, VGG19 features for its perceptual loss (and other helpers' models)."""
