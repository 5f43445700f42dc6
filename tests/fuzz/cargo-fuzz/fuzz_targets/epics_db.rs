#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| zmotor_fuzz::epics_db(data));
