#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| spinedrr_fuzz::drr_tiff(data));
