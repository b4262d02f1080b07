//! Signal analysis for shimmy (MODEL.md §11): band-pass, peak amplitude, Welch PSD, dominant
//! frequency, spectral concentration, Morlet CWT, Lyapunov exponents. Works on plain slices;
//! knows nothing of CAN or the model's internals.
