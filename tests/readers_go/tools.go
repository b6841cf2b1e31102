//go:build tools

// The uv3dp command line itself, built by the test fixture and .ci/run with
// `go build github.com/ezrec/uv3dp/cmd/uv3dp`; importing it here keeps its
// dependencies in go.mod and go.sum.
package main

import _ "github.com/ezrec/uv3dp/cmd/uv3dp"
