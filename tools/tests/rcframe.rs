//! The `rcframe` binary, run as a user would: every worked example of the brief edition's §5
//! encoded from its description and decoded back, bad BCCs, captures with noise, bad input.

use serde_json::{json, Value};
use std::io::Write;
use std::process::{Command, Output, Stdio};

fn run(args: &[&str], stdin: Option<&str>) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_rcframe"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start rcframe");
    let mut pipe = child.stdin.take().expect("stdin");
    pipe.write_all(stdin.unwrap_or("").as_bytes())
        .expect("write stdin");
    drop(pipe);
    child.wait_with_output().expect("run rcframe")
}

fn rcframe(args: &[&str]) -> Output {
    run(args, None)
}

fn stdout(out: &Output) -> String {
    String::from_utf8(out.stdout.clone()).expect("UTF-8 output")
}

/// `rcframe encode <args>`, which must succeed with one line.
fn encode(args: &str) -> String {
    let words: Vec<&str> = std::iter::once("encode")
        .chain(args.split_whitespace())
        .collect();
    let out = rcframe(&words);
    let text = stdout(&out);
    assert_eq!(
        out.status.code(),
        Some(0),
        "encode {args}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(text.lines().count(), 1, "encode {args}: {text:?}");
    text.trim_end().to_owned()
}

/// The JSON lines printed, each parsed.
fn json_lines(out: &Output) -> Vec<Value> {
    stdout(out)
        .lines()
        .map(|line| serde_json::from_str(line).unwrap_or_else(|e| panic!("{line}: {e}")))
        .collect()
}

/// `rcframe decode <args>`: the one JSON object and the exit status.
fn decode(args: &[&str]) -> (Value, i32) {
    let out = rcframe(&[&["decode"], args].concat());
    let mut lines = json_lines(&out);
    assert_eq!(lines.len(), 1, "decode {args:?}: {}", stdout(&out));
    (lines.remove(0), out.status.code().expect("exit status"))
}

// ---------------------------------------------------------------- the brief edition's §5

/// (section, `encode` arguments, the frame as printed, typos corrected).
const EXAMPLES: &[(&str, &str, &str)] = &[
    ("5-1 1 status inquiry", "0 n", "0n000000000082"),
    ("5-1 2 position move", "1 Q3 --point 6", "1Q301060000094"),
    ("5-2 1 home", "3 o --home motor", "3o070000000077"),
    (
        "5-2 2 velocity/acceleration",
        "2 v --mm-s 100 --g 0.2 --lead 2.5",
        "2v22EE001D602F",
    ),
    (
        "5-2 2 raw values",
        "2 v --vel 0x2EE0 --acc 470",
        "2v22EE001D602F",
    ),
    // Printed "0Q3010B00000089": one '0' too many; BCC 89 is that of the 12 characters.
    ("5-2 3 position move", "0 Q3 --point 11", "0Q3010B0000089"),
    (
        "5-2 4 absolute move",
        "C a --mm 56.8 --lead 6 --home motor",
        "CaFFFFE26A00F6",
    ),
    // The second frame of 5-2 5 as printed (valid, though its value is -56.8 mm, not -100).
    (
        "5-2 5 incremental, printed",
        "C m --pulses 0x1D95",
        "Cm00001D95004D",
    ),
    ("5-2 6 servo on", "1 q on", "1q10000000007D"),
    ("5-2 6 servo off", "1 q off", "1q00000000007E"),
    (
        "5-2 7 position inquiry",
        "0 R4 --address 7400",
        "0R40000740008F",
    ),
    ("5-3 1 load point 14", "5 Q1 --point 14", "5Q1010E0000083"),
    ("5-3 1 address PCMD", "5 T4 --address 400", "5T40000040008F"),
    // Printed "5W4FFFFFF352018": one 'F' too many; BCC 18 is that of the 12 characters.
    (
        "5-3 1 write 32.45 mm",
        "5 W4 --mm 32.45 --lead 8 --home motor",
        "5W4FFFFF352018",
    ),
    ("5-3 1 store point 14", "5 V5 --point 14", "5V5010E000007A"),
    (
        "5-3 2 address VCMD",
        "5 T4 --address 0x404",
        "5T40000040408B",
    ),
    ("5-3 2 velocity", "5 W4 --data EA6", "5W400000EA6064"),
    ("5-3 2 address ACMD", "5 T4 --address 405", "5T40000040508A"),
    ("5-3 2 acceleration", "5 W4 --data 0x93", "5W400000093084"),
    ("5-3 2 address FLGP", "5 T4 --address 401", "5T40000040108E"),
    ("5-3 2 flags", "5 W4 --data C0", "5W4000000C007D"),
    ("5-3 2 address INP", "5 T4 --address 403", "5T40000040308C"),
    ("5-3 2 band", "5 W4 --data A", "5W40000000A07F"),
    ("5-3 2 address MXAC", "5 T4 --address 409", "5T400000409086"),
    ("5-3 2 max acc flag", "5 W4 --data 0", "5W400000000090"),
    (
        "5-4 1 jog forward",
        "0 a --pulses 0xFFFF6543",
        "0aFFFF65430025",
    ),
    ("5-4 1 stop", "0 d", "0d00000000008C"),
    ("5-4 2 jog backward", "0 a --pulses -1", "0aFFFFFFFF00DF"),
];

#[test]
fn every_example_of_section_5_encodes_to_the_printed_frame() {
    for (section, args, frame) in EXAMPLES {
        assert_eq!(encode(args), *frame, "§{section}: encode {args}");
    }
}

#[test]
fn every_example_of_section_5_decodes_to_its_axis_and_code() {
    for (section, args, frame) in EXAMPLES {
        let mut words = args.split_whitespace();
        let axis = u8::from_str_radix(words.next().unwrap(), 16).unwrap();
        let code = words.next().unwrap();
        let (json, status) = decode(&[frame]);
        assert_eq!(status, 0, "§{section}: {json}");
        assert_eq!(json["axis"], axis, "§{section}: {json}");
        assert_eq!(json["code"], code, "§{section}: {json}");
        assert_eq!(json["direction"], "request", "§{section}: {json}");
        assert_eq!(json["bcc_ok"], true, "§{section}: {json}");
        assert_eq!(json["frame"], *frame, "§{section}: {json}");
    }
}

#[test]
fn the_briefs_three_examples() {
    assert_eq!(
        encode("C a --mm 56.8 --lead 6 --home motor"),
        "CaFFFFE26A00F6"
    );
    assert_eq!(
        encode("2 v --mm-s 100 --g 0.2 --lead 2.5"),
        "2v22EE001D602F"
    );
    assert_eq!(encode("0 n"), "0n000000000082");
}

#[test]
fn section_5_2_5_incremental_plus_100_printed_with_a_bad_bcc() {
    // Printed "CmFFFFE26A00F6": the 'a' example's data and BCC with 'm'.
    let (json, status) = decode(&["CmFFFFE26A00F6"]);
    assert_eq!(status, 1);
    assert_eq!(json["bcc_ok"], false);
    assert_eq!(json["bcc_expected"], "EA");
    assert_eq!(json["bcc_received"], "F6");
    // The fields are still decoded from the data characters.
    assert_eq!(json["code"], "m");
    assert_eq!(json["axis"], 12);
    assert_eq!(json["pulses"], -7574);
    assert_eq!(json["wire"], "FFFFE26A");
    assert!(json.get("error").is_none(), "{json}");
    // What the rule gives for +100 mm and -100 mm.
    let plus = encode("C m --mm 100 --lead 6 --home motor");
    assert_eq!(plus, "CmFFFFCBEA00CD");
    let minus = encode("C m --mm -100 --lead 6 --home motor");
    assert_eq!(minus, "Cm000034150063");
    let (json, _) = decode(&[&minus, "--lead", "6", "--home", "motor"]);
    assert_eq!(json["mm"], -100.0);
}

#[test]
fn section_5_2_7_position_response_in_mm() {
    let (json, status) = decode(&["U0R4FFFF167AFE", "--lead", "12", "--home", "motor"]);
    assert_eq!(status, 0);
    assert_eq!(json["direction"], "response");
    assert_eq!(json["axis"], 0);
    assert_eq!(json["code"], "R4");
    assert_eq!(
        json["value"],
        json!({"hex": "FFFF167A", "decimal": 0xFFFF_167A_u32})
    );
    assert_eq!(json["pulses"], -59782);
    assert_eq!(json["mm"].as_f64(), Some(896.72));
    assert_eq!(json["bcc_ok"], true);
    // Without the scale, no mm.
    let (json, _) = decode(&["U0R4FFFF167AFE"]);
    assert!(json.get("mm").is_none(), "{json}");
}

#[test]
fn section_5_2_7_request_names_the_register() {
    let (json, _) = decode(&["0R40000740008F"]);
    assert_eq!(json["address"], "00007400");
    assert_eq!(json["register"], "PNOW");
}

#[test]
fn section_5_3_1_position_write_in_mm() {
    let (json, status) = decode(&["5W4FFFFF352018", "--lead", "8", "--home", "motor"]);
    assert_eq!(status, 0);
    assert_eq!(json["data"]["hex"], "FFFFF352");
    assert_eq!(json["mm"].as_f64(), Some(32.45));
}

// ---------------------------------------------------------------- fields

#[test]
fn decoded_fields() {
    let cases: &[(&[&str], Value)] = &[
        (&["0Q3010B0000089"], json!({"point": 11})),
        (&["5Q1010E0000083"], json!({"point": 14})),
        (
            &["0aFFFFE0C0000F"],
            json!({"pulses": -8000, "wire": "FFFFE0C0"}),
        ),
        (
            &[
                "0aFFFFE0C0000F",
                "--lead",
                "10",
                "--home",
                "motor",
                "--twos",
            ],
            json!({"pulses": -8000, "mm": 100.0}),
        ),
        (&["3o070000000077"], json!({"home": "motor"})),
        (&["1q10000000007D"], json!({"servo": "on"})),
        (
            &["2v22EE001D602F", "--lead", "2.5"],
            json!({"vel": 12000, "acc": 470, "mm_s": 100.0, "g": 0.2}),
        ),
        (
            &["0Q20100000009C"],
            json!({"code": "Q2", "position_data": true}),
        ),
    ];
    for (args, fields) in cases {
        let (json, status) = decode(args);
        assert_eq!(status, 0, "{args:?}: {json}");
        for (key, value) in fields.as_object().unwrap() {
            assert_eq!(&json[key], value, "{args:?} {key}: {json}");
        }
    }
}

#[test]
fn buffered_command_is_nested() {
    let frame = encode("0 h a --mm 100 --lead 10 --home motor --twos");
    assert_eq!(frame, "0haFFFFE0C00D7");
    let (json, status) = decode(&[&frame]);
    assert_eq!(status, 0);
    assert_eq!(json["code"], "h");
    assert_eq!(
        json["buffered"],
        json!({"code": "a", "pulses": -8000, "wire": "FFFFE0C0"})
    );
}

#[test]
fn ones_complement_is_the_default() {
    let ones = encode("0 a --mm 100 --lead 10 --home motor");
    assert_eq!(&ones[..12], "0aFFFFE0BF00");
    let (json, status) = decode(&[&ones]);
    assert_eq!((json["wire"].as_str(), status), (Some("FFFFE0BF"), 0));
}

#[test]
fn status_response() {
    // Servo on, ready, homed; PFIN, ZFIN and *ALM (no alarm) on.
    let (json, status) = decode(&["U0n0F0000B0035"]);
    assert_eq!(status, 0);
    assert_eq!(json["code"], "n");
    assert_eq!(json["direction"], "response");
    assert_eq!(
        json["status"],
        json!({"power": true, "servo": true, "run": true, "home": true, "buffered": false,
               "plus_interlock": false, "minus_interlock": false, "rejected": false})
    );
    assert_eq!(json["alarm"]["code"], "00");
    assert_eq!(json["alarm"]["level"], "normal");
    assert_eq!(json["outputs"]["PFIN"], true);
    assert_eq!(json["outputs"]["ZFIN"], true);
    assert_eq!(json["outputs"]["*ALM"], true);
    assert_eq!(json["outputs"]["pm"], 0);
    assert_eq!(json["inputs"]["START"], false);
    assert_eq!(json["rejected"], false);
}

#[test]
fn rejected_response() {
    // A controller rejecting `a` before homing: Status bit 7, warning 71.
    let reply = protocol::Reply::Status {
        axis: protocol::Axis::new(1).unwrap(),
        code: protocol::Code::MoveAbsolute,
        report: protocol::StatusReport {
            status: protocol::Status::from_bits(0x87),
            alarm: protocol::AlarmCode(0x71),
            inputs: protocol::Inputs::from_bits(0x10),
            outputs: protocol::Outputs::from_bits(0x83),
        },
    };
    let text = String::from_utf8(reply.emit().to_text().to_vec()).unwrap();
    let (json, status) = decode(&[&text]);
    assert_eq!(status, 0, "a valid frame, though a rejection: {json}");
    assert_eq!(json["axis"], 1);
    assert_eq!(json["code"], "a");
    assert_eq!(json["rejected"], true);
    assert_eq!(json["status"]["rejected"], true);
    assert_eq!(json["status"]["home"], false);
    assert_eq!(json["alarm"]["code"], "71");
    assert_eq!(json["alarm"]["level"], "warning");
    assert_eq!(json["alarm"]["text"], protocol::AlarmCode(0x71).text());
    assert_eq!(json["inputs"]["START"], true);
    assert_eq!(json["outputs"]["pm"], 3);
}

#[test]
fn memory_responses_carry_a_value() {
    // Complete edition §4-4-3: W4 answers with the next address.
    let (json, status) = decode(&["U3W40000000D59"]);
    assert_eq!(status, 0);
    assert_eq!(
        (json["axis"].as_u64(), json["code"].as_str()),
        (Some(3), Some("W4"))
    );
    assert_eq!(json["value"], json!({"hex": "0000000D", "decimal": 13}));
}

#[test]
fn invalid_data_with_a_right_bcc() {
    let (json, status) = decode(&["0X000000000098"]);
    assert_eq!(status, 1);
    assert_eq!(json["bcc_ok"], true);
    assert_eq!(json["error"], "unknown command 0x58 0x00");
}

#[test]
fn frame_of_the_wrong_length() {
    // §5-2 3 as printed: 15 characters.
    let (json, status) = decode(&["0Q3010B00000089"]);
    assert_eq!(status, 1);
    assert_eq!(json["error"], "frame is 17 bytes, expected 16");
}

// ---------------------------------------------------------------- hex forms

#[test]
fn hex_output_and_hex_input() {
    let hex = encode("0 n --hex");
    assert_eq!(hex, "02 30 6E 30 30 30 30 30 30 30 30 30 30 38 32 03");
    let (text_form, _) = decode(&["0n000000000082"]);
    let forms = [
        hex.clone(),
        hex.to_lowercase(),
        hex.replace(' ', ""),
        hex.split(' ')
            .map(|b| format!("0x{b}"))
            .collect::<Vec<_>>()
            .join(","),
    ];
    for form in &forms {
        let (json, status) = decode(&[form]);
        assert_eq!((&json, status), (&text_form, 0), "{form}");
    }
    // Separate arguments, as an unquoted paste.
    let words: Vec<&str> = hex.split(' ').collect();
    assert_eq!(decode(&words).0, text_form);
}

#[test]
fn communication_change_broadcast() {
    let enq = format!("02 {}03", "05 ".repeat(14));
    assert_eq!(encode("enq"), enq);
    assert_eq!(encode("0 enq --hex"), enq);
    let (json, status) = decode(&[&enq]);
    assert_eq!((json, status), (json!({"packet": "comm_change"}), 0));
}

// ---------------------------------------------------------------- captures

const NOISY_CAPTURE: &str = "\
# noise, two frames, noise, a frame (0x prefixes, commas), noise
FF 00 41
02 30 6E 30 30 30 30 30 30 30 30 30 30 38 32 03   # 0n status request
EE EE
02 55 30 6E 30 46 30 30 30 30 42 30 30 33 35 03   # its answer
0x7F,
0x02,0x31,0x71,0x31,0x30,0x30,0x30,0x30,0x30,0x30,0x30,0x30,0x30,0x37,0x44,0x03
41
";

#[test]
fn capture_with_noise_between_frames() {
    let out = run(&["decode", "-", "--summary"], Some(NOISY_CAPTURE));
    assert_eq!(out.status.code(), Some(0), "{}", stdout(&out));
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 4, "3 frames and the summary: {lines:?}");
    let codes: Vec<(&str, &str)> = lines[..3]
        .iter()
        .map(|l| {
            (
                l["direction"].as_str().unwrap(),
                l["code"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        codes,
        [("request", "n"), ("response", "n"), ("request", "q")]
    );
    assert!(lines[..3].iter().all(|l| l["bcc_ok"] == true));
    assert_eq!(
        lines[3],
        json!({"summary": {"packets": 3, "errors": 0, "noise_bytes": 7}})
    );
}

#[test]
fn capture_from_a_file_and_from_an_argument() {
    let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("rcframe-capture.txt");
    std::fs::write(&path, NOISY_CAPTURE).unwrap();
    let out = rcframe(&["decode", "--file", path.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0));
    assert_eq!(json_lines(&out).len(), 3);
    // Two frames in one argument are a capture too.
    let two = "02 30 6E 30 30 30 30 30 30 30 30 30 30 38 32 03 00 \
               02 30 64 30 30 30 30 30 30 30 30 30 30 38 43 03";
    let out = rcframe(&["decode", two]);
    let lines = json_lines(&out);
    assert_eq!(out.status.code(), Some(0));
    assert_eq!(lines.len(), 2);
    assert_eq!(
        (&lines[0]["code"], &lines[1]["code"]),
        (&json!("n"), &json!("d"))
    );
}

#[test]
fn capture_reports_every_bad_candidate() {
    let capture = "\
        02 43 6D 46 46 46 46 45 32 36 41 30 30 46 36 03 # CmFFFFE26A00F6: bad BCC
        02 30 6E 30 30                                  # cut short by the next STX
        02 05 05 05 05 05 05 05 05 05 05 05 05 05 05 03 # communication change
        02 30 58 30 30 30 30 30 30 30 30 30 30 39 38 03 # BCC right, unknown command
        02 30 6E 30 30 30 30 30 30 30 30 30 30 38 32 04 # no ETX
        02 30 6E                                        # end of input inside a frame
    ";
    let out = run(&["decode", "-", "--summary"], Some(capture));
    assert_eq!(out.status.code(), Some(1));
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 7, "{lines:?}");
    assert_eq!(lines[0]["bcc_expected"], "EA");
    assert_eq!(lines[0]["code"], "m");
    assert_eq!(lines[0]["error"], "bad BCC: expected EA, received F6");
    assert_eq!(
        lines[0]["rejected"],
        "02 43 6D 46 46 46 46 45 32 36 41 30 30 46 36 03"
    );
    assert_eq!(lines[1]["rejected"], "02 30 6E 30 30");
    assert_eq!(lines[1]["error"], "frame cut short after 5 bytes");
    assert_eq!(lines[2], json!({"packet": "comm_change"}));
    assert_eq!(lines[3]["error"], "unknown command 0x58 0x00");
    assert_eq!(lines[4]["error"], "expected ETX (0x03), found 0x04");
    assert_eq!(lines[5]["rejected"], "02 30 6E");
    assert_eq!(
        lines[6],
        json!({"summary": {"packets": 2, "errors": 5, "noise_bytes": 0}})
    );
}

#[test]
fn capture_without_a_frame_fails() {
    let out = run(&["decode", "-"], Some("# nothing but noise\nFF 00 41\n"));
    assert_eq!(out.status.code(), Some(1));
    assert!(json_lines(&out).is_empty());
}

// ---------------------------------------------------------------- bad input

#[test]
fn bad_command_line_input_exits_2() {
    let cases: &[&[&str]] = &[
        &[
            "encode", "C", "a", "--mm", "56.801", "--lead", "6", "--home", "motor",
        ],
        &[
            "encode", "C", "a", "--mm", "abc", "--lead", "6", "--home", "motor",
        ],
        &["encode", "C", "a", "--mm", "56.8", "--lead", "6"],
        &[
            "encode", "C", "a", "--mm", "56.8", "--lead", "0", "--home", "motor",
        ],
        &["encode", "G", "n"],
        &["encode", "16", "n"],
        &["encode", "n"],
        &["encode", "0", "x"],
        &["encode", "0", "Q3", "--point", "16"],
        &["encode", "0", "Q1", "--point", "1", "--common"],
        &["encode", "0", "h", "R4", "--address", "7400"],
        &["encode", "0", "R4", "--address", "123456789"],
        &["encode", "0", "p", "--rtim", "2"],
        &["encode", "0", "v", "--vel", "0x57E5", "--acc", "1"],
        &["encode", "0", "v", "--vel", "100", "--acc", "0"],
        &["encode", "0", "v", "--mm-s", "100", "--acc", "1"],
        &["decode"],
        &["decode", "02 zz"],
        &["decode", "--file", "/nonexistent/capture.txt"],
    ];
    for args in cases {
        let out = rcframe(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stdout(&out));
        assert!(out.stdout.is_empty(), "{args:?}");
        assert!(!out.stderr.is_empty(), "{args:?}");
    }
}

#[test]
fn empty_input_is_bad_input_with_a_message() {
    let dir = std::env::temp_dir().join(format!("rcframe-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let empty = dir.join("empty.txt");
    std::fs::write(&empty, "").expect("write");
    let comments = dir.join("comments.txt");
    std::fs::write(&comments, "# a capture header, no bytes\n\n").expect("write");
    let (empty, comments) = (
        empty.to_str().expect("path"),
        comments.to_str().expect("path"),
    );
    for (args, stdin, says) in [
        (&["decode", ""][..], "", "the argument holds no frame"),
        (&["decode", "  "][..], "", "the argument holds no frame"),
        (
            &["decode", "--file", empty][..],
            "",
            "empty.txt holds no frame",
        ),
        (
            &["decode", "--file", comments][..],
            "",
            "comments.txt holds no frame",
        ),
        (&["decode", "-"][..], "", "standard input holds no frame"),
    ] {
        let out = run(args, Some(stdin));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(out.stdout.is_empty(), "{args:?}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
    // Noise only is a capture without a frame: exit status 1, and the reason on stderr.
    let out = run(&["decode", "-"], Some("FF 00 41\n"));
    assert_eq!(out.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no frame in the capture's 3 bytes"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn alarm_texts_come_from_the_codec_table() {
    let out = rcframe(&["alarm", "E0"]);
    assert_eq!(out.status.code(), Some(0));
    let line: Value = serde_json::from_str(stdout(&out).trim()).unwrap();
    assert_eq!(line["code"], "E0");
    assert_eq!(line["level"], "Error");
    assert_eq!(line["text"], protocol::alarm::AlarmCode(0xE0).text());

    let all = stdout(&rcframe(&["alarm"]));
    let codes: Vec<Value> = all
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(codes.iter().any(|c| c["code"] == "B1"), "{all}");
    assert!(codes.len() > 10, "{all}");

    assert_eq!(rcframe(&["alarm", "zz"]).status.code(), Some(2));
}
