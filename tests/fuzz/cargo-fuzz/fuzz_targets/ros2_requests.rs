#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| zmotor_fuzz::ros2_requests(data));
