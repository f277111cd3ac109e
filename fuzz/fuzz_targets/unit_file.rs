#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| spinedrr_fuzz::unit_file(data));
