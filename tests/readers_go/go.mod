module skelslice/tests/readers_go

go 1.24.0

require github.com/ezrec/uv3dp v1.2.12

require (
	github.com/go-restruct/restruct v1.2.0-alpha // indirect
	github.com/pkg/errors v0.9.1 // indirect
	github.com/spf13/pflag v1.0.10 // indirect
	golang.org/x/image v0.34.0 // indirect
)
