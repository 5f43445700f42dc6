#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| zmotor_fuzz::write_decoders(data));
