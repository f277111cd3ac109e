//! Projection-domain metrics.
