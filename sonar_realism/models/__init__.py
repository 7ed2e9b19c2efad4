"""The model side, in one package: the networks (cDFCVAE, CycleGAN baseline, speckle, VGG19 features, realism
CNN), the data they train on (`datasets`), their training (`train`, `train_cyclegan`), sampling and the one
checkpoint loader (`translate`), and the device rule they share (`device`)."""
